//! Model directories as the engines load them: a manifest's file and its refine base stay among the shipped
//! models' directories (real ONNX Runtime, the shipped networks).
use std::path::Path;

#[test]
fn a_disparity_manifest_naming_a_file_outside_its_directory_is_refused() {
    use abvs_disparity::onnx::OnnxEngine;
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/hitnet/hitnet-s/manifest.json");
    let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(shipped).unwrap()).unwrap();
    for (file, what) in [("../hitnet-m/model.onnx", "leaves its directory"), ("/tmp/model.onnx", "is absolute")] {
        let d = tempfile::tempdir().unwrap();
        m["file"] = serde_json::json!(file);
        std::fs::write(d.path().join("manifest.json"), m.to_string()).unwrap();
        let e = OnnxEngine::load(d.path(), 1).err().expect("refused").to_string();
        assert!(e.contains("manifest.json") && e.contains("`file`") && e.contains(what), "{e}");
    }
}

#[test]
fn census_refine_runs_the_refine_base_a_manifest_names_and_refuses_one_outside_its_siblings() {
    use abvs_disparity::factory::engine;
    use abvs_disparity::manifest::refine_base;
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/hitnet");
    // the shipped hitnet-m names hitnet-s, which exists and loads; census-refine reports it by name, with
    // the SGBM prior it runs at the network's 320x240 (below the engine's 640x480)
    let base = refine_base(&models.join("hitnet-m")).unwrap();
    assert_eq!(base.file_name().unwrap(), "hitnet-s");
    assert!(base.join("manifest.json").is_file(), "{}", base.display());
    let e = engine("census-refine", Some(&models.join("hitnet-m")), (640, 480), 64.0, 1).unwrap();
    assert_eq!(e.name(), "census-refine:hitnet-s+sgbm");
    // hitnet-m4 names none: at its own 640x480 it runs alone, refined at the engine's resolution
    let e = engine("census-refine", Some(&models.join("hitnet-m4")), (640, 480), 64.0, 1).unwrap();
    assert_eq!(e.name(), "census-refine:hitnet-m4");
    // a model without one is its own base; an .onnx file too
    assert_eq!(refine_base(&models.join("hitnet-s")).unwrap(), models.join("hitnet-s"));
    let onnx = models.join("hitnet-s/model.onnx");
    assert_eq!(refine_base(&onnx).unwrap(), onnx);
    let shipped = models.join("hitnet-m/manifest.json");
    let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(shipped).unwrap()).unwrap();
    for bad in ["../hitnet-m4", "/tmp/hitnet-m4", "a/b", ".."] {
        let d = tempfile::tempdir().unwrap();
        m["refine_base"] = serde_json::json!(bad);
        std::fs::write(d.path().join("manifest.json"), m.to_string()).unwrap();
        let e = refine_base(d.path()).expect_err("refused").to_string();
        assert!(e.contains("manifest.json") && e.contains("`refine_base`") && e.contains(bad), "{e}");
    }
    // a sibling that is not there is named when it is loaded
    let d = tempfile::tempdir().unwrap();
    m["refine_base"] = serde_json::json!("no-such-model");
    std::fs::write(d.path().join("manifest.json"), m.to_string()).unwrap();
    let e = engine("census-refine", Some(d.path()), (640, 480), 64.0, 1).err().expect("refused").to_string();
    assert!(e.contains("no-such-model"), "{e}");
}
