//! `abvs run --rerun FILE`: with the `rerun` feature the replay is logged to an .rrd file that
//! rerun's own decoder reads back, with every entity logged once per frame; without the feature
//! the flag is refused with a clear message.
use std::process::Command;

#[cfg(feature = "rerun")]
#[test]
fn replay_is_logged_to_a_rerun_file() {
    use std::collections::BTreeMap;
    let tmp = tempfile::tempdir().unwrap();
    let rrd = tmp.path().join("run.rrd");
    let json = tmp.path().join("stats.json");
    let frames = 6;
    let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args([
            "run",
            "--resolution",
            "320x240",
            "--engine",
            "sgbm",
            "--no-publish",
            "--lossless",
            "--quiet",
            "--frames",
            &frames.to_string(),
        ])
        .arg("--rerun")
        .arg(&rrd)
        .arg("--stats-json")
        .arg(&json)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["rerun"]["frames"], serde_json::json!(frames), "{v}");
    assert_eq!(v["rerun"]["errors"], serde_json::json!(0), "{v}");

    // Read the file back with rerun's decoder: rows per entity.
    let file = std::io::BufReader::new(std::fs::File::open(&rrd).unwrap());
    let decoder = rerun::external::re_log_encoding::DecoderApp::decode_eager(file).unwrap();
    let mut rows: BTreeMap<String, usize> = BTreeMap::new();
    for msg in decoder {
        if let rerun::log::LogMsg::ArrowMsg(_, arrow) = msg.unwrap() {
            let chunk = rerun::log::Chunk::from_arrow_msg(&arrow).unwrap();
            *rows.entry(chunk.entity_path().to_string()).or_default() += chunk.num_rows();
        }
    }
    eprintln!("{rows:#?}");
    for (entity, per_frame) in [
        ("/world/cloud", 1),
        ("/world/left", 1),
        ("/world/right", 1),
        // transform + pinhole
        ("/world/left/rectified", 2),
        ("/world/right/rectified", 2),
        ("/world/left/rectified/image", 1),
        ("/world/right/rectified/image", 1),
        ("/world/left/rectified/depth", 1),
    ] {
        assert_eq!(rows.get(entity).copied(), Some(per_frame * frames), "{entity}: {rows:?}");
    }
}

#[cfg(not(feature = "rerun"))]
#[test]
fn rerun_flag_without_the_feature_is_refused_clearly() {
    let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args([
            "run",
            "--resolution",
            "320x240",
            "--engine",
            "sgbm",
            "--no-publish",
            "--frames",
            "1",
            "--rerun",
            "x.rrd",
        ])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("--features rerun"), "{e}");
}
