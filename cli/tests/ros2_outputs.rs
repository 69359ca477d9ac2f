//! The ROS 2 outputs and the Python subscriber against a real `abvs run` on the fixture, checked from
//! Python (python/tests/abvs_check.py): Zenoh (eclipse-zenoh + rosbags), MCAP (mcap + mcap-ros2-support)
//! and the iceoryx2 services (python/abvs_iceoryx2.py). The Python environment comes from
//! scripts/setup.sh (.deps/python, or the interpreter in ABVS_PYTHON); without it these tests fail.
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};

use serde_json::Value;

#[path = "../../tests/support/python_env.rs"]
mod python_env;
use python_env::{python, repo};

/// A unique iceoryx2 service prefix per test (tests of one binary run at once).
fn prefix(test: &str) -> String {
    format!("abvs-t{}-{test}", std::process::id())
}

/// Starts the Python check and waits for its "ready" line (its subscribers exist).
fn start_check(args: &[&str]) -> (Child, BufReader<ChildStdout>) {
    let mut child = Command::new(python())
        .arg(repo().join("python/tests/abvs_check.py"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("starting python");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    assert_eq!(line.trim(), "ready", "python check {args:?} did not start (see its stderr above)");
    (child, out)
}

/// Closes the check's stdin (the run is over) and reads its JSON result.
fn finish_check(mut child: Child, mut out: BufReader<ChildStdout>) -> Value {
    drop(child.stdin.take());
    let mut text = String::new();
    std::io::Read::read_to_string(&mut out, &mut text).unwrap();
    let st = child.wait().unwrap();
    assert!(st.success(), "python check failed: {st:?}\n{text}");
    serde_json::from_str(text.lines().last().unwrap_or("")).unwrap_or_else(|e| panic!("{e}: {text}"))
}

/// `abvs run` on the fixture (paced at 25 fps) with `extra`; returns its stats JSON.
/// The default configuration, `edit`ed, with `[fovea] shed_when_behind = false`: these checks count one fovea
/// message per published frame, and a debug build's fovea lane, often behind, would let frames go without one
/// (runtime/tests/runner.rs tests the shedding).
fn config(dir: &Path, edit: impl Fn(String) -> String) -> PathBuf {
    let printed = Command::new(env!("CARGO_BIN_EXE_abvs")).args(["run", "--print-config"]).output().unwrap();
    let printed = String::from_utf8(printed.stdout).unwrap();
    assert!(printed.contains("\nshed_when_behind = true\n"), "{printed}");
    let f = dir.join("no_shedding.toml");
    std::fs::write(&f, edit(printed.replace("\nshed_when_behind = true\n", "\nshed_when_behind = false\n"))).unwrap();
    f
}

fn run(dir: &Path, prefix: &str, extra: &[&str]) -> Value {
    let stats = dir.join("stats.json");
    let own = if extra.contains(&"--config") { None } else { Some(config(dir, |s| s)) };
    let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args([
            "run",
            "--resolution",
            "320x240",
            "--quiet",
            "--service-prefix",
            prefix,
            "--stats-json",
            stats.to_str().unwrap(),
        ])
        .args(extra)
        .args(own.iter().flat_map(|f| ["--config".as_ref(), f.as_os_str()]))
        .output()
        .unwrap();
    assert!(o.status.success(), "abvs run: {}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(stats).unwrap()).unwrap()
}

fn published(s: &Value) -> u64 {
    let n = s["frames_published"].as_u64().unwrap();
    // a loaded machine may drop a few of the fixture's 50 frames (counted); the checks are per published frame
    assert!(n >= 25, "the fixture's 50 frames, most of them published: {n}");
    n
}

/// One `abvs run` at a time: three at once on two cores would measure the machine, not the outputs.
static ONE_RUN: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_run() -> std::sync::MutexGuard<'static, ()> {
    ONE_RUN.lock().unwrap_or_else(|e| e.into_inner())
}

#[test]
fn python_iceoryx2_subscriber_receives_the_frames() {
    let _one = one_run();
    let d = tempfile::tempdir().unwrap();
    let p = prefix("iox");
    let (child, out) = start_check(&["iox", &p, "confidence", "fovea"]);
    // the default engine computes a confidence and publishes it (`--confidence` would run a second,
    // right-view pass: twice the disparity stage)
    let s = run(d.path(), &p, &[]);
    let r = finish_check(child, out);
    let n = published(&s) as f64;
    let (depth, cloud) = (r["depth_frames"].as_f64().unwrap(), r["cloud_frames"].as_f64().unwrap());
    let confidence = r["confidence_frames"].as_f64().unwrap();
    println!("published {n}, python received depth {depth}, clouds {cloud}, confidence {confidence}");
    assert!(depth >= 0.95 * n && cloud >= 0.95 * n && confidence >= 0.95 * n, "{r}");
    assert_eq!(r["bad_shapes"], serde_json::json!([]), "depth arrays of the wrong shape: {r}");
    assert_eq!(r["frame_ids"], serde_json::json!(["left_home_camera"]));
    // the confidence: (height, width) float32 in [0, 1], not all 0, with its depth sample's header (by seq)
    assert_eq!(r["bad_confidence"], serde_json::json!([]), "{r}");
    let with_depth = r["confidence_with_depth"].as_f64().unwrap();
    assert!(with_depth >= 0.9 * n, "{r}");
    assert_eq!(r["confidence_same_header"], r["confidence_with_depth"], "{r}");
    // the fovea (on by default): its depth and cloud, the depth's valid count in its header, at the raw frames'
    // focal length (800x600 frames: above the 320x240 main map's)
    let fovea = &r["fovea_frames"];
    assert!(fovea[0].as_f64().unwrap() >= 0.95 * n && fovea[1].as_f64().unwrap() >= 0.95 * n, "{r}");
    assert_eq!(r["fovea_bad"], serde_json::json!([]), "{r}");
    let (ff, mf) = (r["fovea_focal"][0].as_f64().unwrap(), r["main_focal"][0].as_f64().unwrap());
    assert!(r["fovea_focal"].as_array().unwrap().len() == 1 && ff > 2.0 * mf, "{r}");
}

#[test]
fn zenoh_messages_reach_a_python_listener() {
    let _one = one_run();
    let d = tempfile::tempdir().unwrap();
    let p = prefix("zenoh");
    // free loopback ports for the listeners (taken back by the OS a moment before Python binds them): one
    // session with Zenoh shared memory, one without
    let endpoint = free_endpoint();
    let plain = free_endpoint();
    let (child, out) = start_check(&["zenoh", &endpoint, &p, &plain]);
    let s = run(d.path(), &p, &["--zenoh-connect", &endpoint, "--zenoh-connect", &plain]);
    let r = finish_check(child, out);
    let n = published(&s);
    println!("published {n}; zenoh stats {}; python {r}", s["zenoh"]);
    let z = &s["zenoh"];
    assert_eq!(z["frames_in"].as_u64(), Some(n), "{z}");
    assert_eq!(z["frames_failed"].as_u64(), Some(0), "{z}");
    // shared memory (the default): the large messages were written into the pool, none fell back, and the
    // session with shared memory received every large payload as a shared buffer (the one without, none)
    // (a message finding every buffer still held by the subscribers goes the ordinary way, counted: allowed
    // for a few, the pool never makes the sink wait)
    let w = &z["writer"];
    assert_eq!(w["shared_memory"].as_bool(), Some(true), "{z}");
    let (shm, fallbacks) = (w["shm_messages"].as_u64().unwrap(), w["shm_fallbacks"].as_u64().unwrap());
    assert!(shm as f64 >= 2.0 * 0.9 * n as f64 && fallbacks * 50 <= shm, "{z}");
    // the depth map and the cloud written by the depth stage straight into their messages' shared buffers,
    // not copied (the cloud's lent for every pixel and sent as long as its points: checked by length below)
    assert!(z["depth_in_place"].as_u64().unwrap() as f64 >= 0.9 * n as f64, "{z}");
    assert!(z["cloud_in_place"].as_u64().unwrap() as f64 >= 0.9 * n as f64, "{z}");
    for key in ["abvs/depth", "abvs/points", "abvs/fovea/depth", "abvs/confidence"] {
        let large = r["large"][key].as_u64().unwrap();
        assert!(large as f64 >= 0.9 * n as f64, "{key}: {r}");
        assert!(r["large_shm"][key].as_u64().unwrap() + fallbacks >= large, "{key}: {r}");
    }
    assert_eq!(r["plain"]["shm"].as_u64(), Some(0), "{r}");
    for key in [
        "abvs/depth",
        "abvs/camera_info",
        "abvs/points",
        "tf",
        "abvs/joint_states",
        "abvs/fovea/depth",
        "abvs/fovea/camera_info",
        "abvs/fovea/points",
        "abvs/confidence",
    ] {
        let got = r["received"][key].as_u64().unwrap();
        assert!(got as f64 >= 0.9 * n as f64, "{key}: {got} of {n} frames received");
        assert_eq!(r["decoded"][key], r["received"][key], "{key}: every message decodes");
        // the session without shared memory got the same messages, byte for byte
        let plain = r["plain"]["received"][key].as_u64().unwrap();
        assert!(plain as f64 >= 0.9 * n as f64, "{key}: {plain} of {n} frames received without shared memory");
        assert_eq!(r["plain"]["equal"][key].as_u64(), Some(plain), "{key}: {r}");
    }
    // (rosbags refuses a payload of another length than its message: a cloud sent in its whole lent buffer,
    // not shortened to its points, fails here)
    assert_eq!(r["decode_errors"], serde_json::json!([]));
    // every cloud that also came over iceoryx2 (same frame = same stamp) is the same bytes
    let compared = r["clouds_compared"].as_u64().unwrap();
    assert!(compared as f64 >= 0.9 * n as f64, "{r}");
    assert_eq!(r["clouds_equal"].as_u64(), Some(compared), "{r}");
    assert_eq!(r["depth_encoding"], serde_json::json!(["32FC1"]));
    assert_eq!(r["depth_frame_ids"], serde_json::json!(["left_rect_camera"]));
    assert_eq!(r["depth_shape_ok"], Value::Bool(true));
    assert_eq!(
        r["tf"],
        serde_json::json!([
            "left_home_camera->left_camera",
            "left_home_camera->left_rect_camera",
            "left_home_camera->right_camera"
        ])
    );
    assert_eq!(r["joint_names"].as_array().map(|a| a.len()), Some(6));
    // frame_ids and the TF tree agree: the depth unprojected with its K and moved by /tf from
    // left_rect_camera to left_home_camera is the cloud (float32 rounding apart)
    let tf_checked = r["tf_checked"].as_u64().unwrap();
    assert!(tf_checked as f64 >= 0.9 * n as f64, "{r}");
    let err = r["tf_max_err_m"].as_f64().unwrap_or(f64::INFINITY);
    assert!(err < 1e-4, "depth + camera_info + tf vs the cloud: {err} m");
    // the fovea's three topics, frame by frame against its iceoryx2 services: CameraInfo K, P and size are
    // the window's intrinsics and size, the depth has that size and the header's valid count, the cloud is
    // the same bytes (none and all NaN on a motion-gated frame), and depth + CameraInfo + /tf give the cloud
    let f = &r["fovea"];
    let compared = f["compared"].as_u64().unwrap();
    assert!(compared as f64 >= 0.9 * n as f64, "{f}");
    for k in ["info_equal", "depth_equal", "cloud_equal"] {
        assert_eq!(f[k].as_u64(), Some(compared), "{k}: {f}");
    }
    assert_eq!(f["frame_ids"], serde_json::json!(["left_rect_camera"]), "{f}");
    assert_eq!(f["cloud_frame_ids"], serde_json::json!(["left_home_camera"]), "{f}");
    assert_eq!(f["focal_above_main"], Value::Bool(true), "native scale: {f}");
    assert!(f["tf_checked"].as_u64().unwrap() as f64 >= 0.9 * n as f64, "{f}");
    let err = f["tf_max_err_m"].as_f64().unwrap_or(f64::INFINITY);
    assert!(err < 1e-4, "fovea depth + camera_info + tf vs its cloud: {err} m");
    // the confidence (the default engine computes one): the iceoryx2 confidence's bytes, frame by frame, in
    // the depth image's size and frame; no published depth pixel without a confidence
    let c = &r["confidence"];
    let compared = c["compared"].as_u64().unwrap();
    assert!(compared as f64 >= 0.9 * n as f64, "{c}");
    assert_eq!(c["equal"].as_u64(), Some(compared), "{c}");
    assert_eq!(c["encodings"], serde_json::json!(["32FC1"]), "{c}");
    assert_eq!(c["frame_ids"], serde_json::json!(["left_rect_camera"]), "{c}");
    assert_eq!(c["finite_depth_unconfident"].as_u64(), Some(0), "{c}");
}

/// A loopback endpoint on a free port (taken back by the OS a moment before Python binds it).
fn free_endpoint() -> String {
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    format!("tcp/127.0.0.1:{port}")
}

#[test]
fn topics_nobody_receives_are_neither_copied_nor_encoded() {
    let _one = one_run();
    let d = tempfile::tempdir().unwrap();
    let p = prefix("matching");
    let endpoint = free_endpoint();
    let (child, out) = start_check(&["count", &endpoint, "abvs/depth"]);
    let s =
        run(d.path(), &p, &["--zenoh-connect", &endpoint, "--frames", "24", "--truth-stride", "0", "--no-self-check"]);
    let r = finish_check(child, out);
    let z = &s["zenoh"];
    println!("zenoh stats {z}; python {r}");
    let (written, messages) = (z["frames_written"].as_u64().unwrap(), z["messages"].as_u64().unwrap());
    assert!(written >= 6 && z["frames_failed"].as_u64() == Some(0), "{z}");
    // only the depth was written (from the frame whose subscriber had matched), and it arrived; the other
    // eight topics (the cloud and the confidence among them) were skipped every frame
    assert!(messages >= written / 2 && messages <= written, "{z}");
    assert_eq!(r["received"]["abvs/depth"].as_u64(), Some(messages), "{r}");
    assert_eq!(z["messages_skipped"].as_u64(), Some(9 * written - messages), "{z}");
}

#[test]
fn rmw_zenoh_node_is_seen_by_a_python_client() {
    let _one = one_run();
    let d = tempfile::tempdir().unwrap();
    let p = prefix("rmw");
    let endpoint = free_endpoint();
    // the runtime's shared memory off here (on in the bridge keys' test): the large messages go out of the
    // snapshot's own buffers, and decode all the same
    let cfg = config(d.path(), |printed| {
        assert!(printed.contains("\nshared_memory = true\n"), "{printed}");
        printed.replace("\nshared_memory = true\n", "\nshared_memory = false\n")
    });
    let (child, out) = start_check(&["rmw", &endpoint]);
    let args = ["--zenoh-connect", &endpoint, "--ros2-keys", "rmw-zenoh", "--ros-distro", "jazzy"];
    let more = ["--frames", "24", "--truth-stride", "0", "--no-self-check", "--config", cfg.to_str().unwrap()];
    let s = run(d.path(), &p, &[&args[..], &more].concat());
    let r = finish_check(child, out);
    let z = &s["zenoh"];
    println!("zenoh stats {z}; python {r}");
    assert_eq!(z["writer"]["shared_memory"], Value::Bool(false), "{z}");
    let written = z["frames_written"].as_u64().unwrap();
    assert!(written >= 6 && z["frames_failed"].as_u64() == Some(0), "{z}");
    assert_eq!(r["decode_errors"], serde_json::json!([]));
    assert_eq!(r["attachment_errors"], serde_json::json!([]));
    assert_eq!(r["token_errors"], serde_json::json!([]));
    // the node: zid of the session that connected, node id 0 = entity id 0, root enclave and namespace
    assert_eq!(
        r["node"],
        serde_json::json!({"zid_is_peer": true, "ids": ["0", "0"], "enclave_ns_name": ["%", "%", "abvs"]})
    );
    let mut ids = Vec::new();
    let topics = [
        "/abvs/depth",
        "/abvs/camera_info",
        "/abvs/points",
        "/tf",
        "/abvs/joint_states",
        "/abvs/fovea/depth",
        "/abvs/fovea/camera_info",
        "/abvs/fovea/points",
        "/abvs/confidence",
    ];
    for topic in topics {
        // every message under the Jazzy key decodes as its type; the subscriber may miss the first few
        // (before its subscription reached the runtime), none after: sequence numbers step by one up to
        // the frames written (one sample a frame, numbered from 1)
        let got = r["received"][topic].as_u64().unwrap();
        assert!(got >= written / 2 && r["decoded"][topic].as_u64() == Some(got), "{topic}: {got} of {written}: {r}");
        assert_eq!(r["seq_steps_ok"][topic], Value::Bool(true), "{topic}: {r}");
        assert_eq!(r["seq_first"][topic].as_u64().unwrap() + got - 1, written, "{topic}: {r}");
        assert_eq!(r["gids"][topic].as_array().map(|a| a.len()), Some(1), "one GID a publisher: {r}");
        let pb = &r["publishers"][topic];
        assert_eq!(pb["zid_is_peer"], Value::Bool(true), "{topic}: {pb}");
        assert_eq!(pb["type_ok"], Value::Bool(true), "{topic}: {pb}");
        assert_eq!(pb["gid_matches_samples"], Value::Bool(true), "{topic}: {pb}");
        assert_eq!(pb["node"], serde_json::json!(["%", "%", "abvs"]), "{topic}: {pb}");
        // sensor data QoS: best effort (2), volatile (2), keep last (1) 5
        assert_eq!(pb["qos"], "2:2:1,5:,:,:,,", "{topic}: {pb}");
        assert_eq!(pb["ids"][0], "0", "{topic}: {pb}");
        ids.push(pb["ids"][1].as_str().unwrap().to_string());
    }
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), topics.len(), "one entity id a publisher: {ids:?}");
    let gids: std::collections::BTreeSet<String> =
        r["gids"].as_object().unwrap().values().map(|g| g[0].as_str().unwrap_or("").to_string()).collect();
    assert_eq!(gids.len(), topics.len(), "one GID a publisher: {r}");
    // the run's end takes the node out of the ROS 2 graph: every token is withdrawn (the node's, the nine
    // outputs' and the gaze state's publisher: goals over Zenoh are off, no subscription)
    assert_eq!(r["tokens"].as_array().map(|a| a.len()), Some(11), "{r}");
    let gaze = r["tokens"].as_array().unwrap().iter().filter(|t| t.as_str().unwrap_or("").contains("%gaze%")).count();
    assert_eq!(gaze, 1, "{r}");
    assert_eq!(r["tokens_gone"], r["tokens"], "{r}");
}

#[test]
fn mcap_recording_decodes_in_python() {
    let _one = one_run();
    let d = tempfile::tempdir().unwrap();
    let p = prefix("mcap");
    let file = d.path().join("out.mcap");
    let (child, out) = start_check(&["mcap", file.to_str().unwrap(), &p]);
    let s = run(d.path(), &p, &["--mcap", file.to_str().unwrap()]);
    let r = finish_check(child, out);
    let n = published(&s);
    println!("published {n}; mcap stats {}; python {r}", s["mcap"]);
    assert_eq!(s["mcap"]["frames_dropped"].as_u64(), Some(0), "{}", s["mcap"]);
    assert_eq!(r["decode_errors"], serde_json::json!([]));
    let types = [
        ("/abvs/depth", "sensor_msgs/msg/Image"),
        ("/abvs/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/abvs/points", "sensor_msgs/msg/PointCloud2"),
        ("/tf", "tf2_msgs/msg/TFMessage"),
        ("/abvs/joint_states", "sensor_msgs/msg/JointState"),
        ("/abvs/fovea/depth", "sensor_msgs/msg/Image"),
        ("/abvs/fovea/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/abvs/fovea/points", "sensor_msgs/msg/PointCloud2"),
        ("/abvs/confidence", "sensor_msgs/msg/Image"),
    ];
    for (topic, ty) in types {
        assert_eq!(r["schemas"][topic], serde_json::json!([ty, "ros2msg", "cdr"]), "{topic}");
        // one message per published frame on every topic: the clouds equal frames_published
        assert_eq!(r["messages"][topic].as_u64(), Some(n), "{topic}: {r}");
    }
    assert_eq!(r["summary_messages"].as_u64(), Some(types.len() as u64 * n));
    assert_eq!(r["profile"], "ros2");
    assert_eq!(r["stamps_back"].as_u64(), Some(0), "stamps never go back");
    // CameraInfo K against the FrameHeader intrinsics of the same frame (received over iceoryx2), the main
    // map's and the fovea's
    let checked = r["k_checked"].as_u64().unwrap();
    assert!(checked as f64 >= 0.9 * 2.0 * n as f64, "{r}");
    assert_eq!(r["k_equal"].as_u64(), Some(checked), "{r}");
}

#[test]
fn print_config_carries_the_ros2_outputs_and_bad_input_is_refused() {
    let abvs = |args: &[&str]| Command::new(env!("CARGO_BIN_EXE_abvs")).args(args).output().unwrap();
    let o = abvs(&[
        "run",
        "--print-config",
        "--zenoh-connect",
        "tcp/10.0.0.2:7447",
        "--zenoh-connect",
        "tcp/10.0.0.3:7447",
        "--mcap",
        "/tmp/x.mcap",
        "--ros2-keys",
        "rmw-zenoh",
        "--ros-distro",
        "humble",
    ]);
    assert!(o.status.success());
    let c: toml::Value = toml::from_str(&String::from_utf8_lossy(&o.stdout)).unwrap();
    let z = &c["bridges"]["zenoh"];
    assert_eq!(z["enabled"].as_bool(), Some(true));
    assert_eq!(z["connect"].as_array().unwrap().len(), 2);
    assert_eq!((z["keys"].as_str(), z["distro"].as_str()), (Some("rmw-zenoh"), Some("humble")));
    assert_eq!(
        (z["node"].as_str(), z["namespace"].as_str(), z["domain"].as_integer()),
        (Some("abvs"), Some("/"), Some(0))
    );
    assert_eq!(c["sinks"]["mcap"]["file"].as_str(), Some("/tmp/x.mcap"));
    // the printed configuration runs as it says (round trip through a file)
    let d = tempfile::tempdir().unwrap();
    let f = d.path().join("r.toml");
    std::fs::write(&f, &o.stdout).unwrap();
    let again = abvs(&["run", "--config", f.to_str().unwrap(), "--print-config"]);
    assert_eq!(again.stdout, o.stdout);
    // a missing Zenoh configuration file, an MCAP file that cannot be created, a zero queue: errors, no panic
    let cases: [(&[&str], &str); 3] = [
        (&["run", "--zenoh-config", "/nonexistent/zenoh.json5"], "/nonexistent/zenoh.json5"),
        (&["run", "--no-publish", "--mcap", "/nonexistent/dir/out.mcap"], "/nonexistent/dir/out.mcap"),
        (&["run", "--zenoh-connect", "not an endpoint"], "not an endpoint"),
    ];
    for (args, says) in cases {
        let o = abvs(args);
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {e}");
        assert!(e.contains(says) && !e.contains("panicked"), "{args:?}: {e}");
    }
    let printed = String::from_utf8_lossy(&o.stdout).to_string();
    let bad = [
        (printed.replace("queue = 16", "queue = 0"), "sinks.mcap.queue"),
        (printed.replace("node = \"abvs\"", "node = \"2abvs\""), "bridges.zenoh.node: `2abvs`"),
        (printed.replace("namespace = \"/\"", "namespace = \"robot\""), "bridges.zenoh.namespace: `robot`"),
        (printed.replace("distro = \"humble\"", "distro = \"iron\""), "`iron`, expected one of `humble`"),
    ];
    for (text, says) in bad {
        std::fs::write(&f, text).unwrap();
        let o = abvs(&["run", "--config", f.to_str().unwrap()]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && e.contains(says) && !e.contains("panicked"), "{says}: {e}");
    }
}
