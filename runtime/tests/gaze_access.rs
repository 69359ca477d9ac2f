//! Who may move the eyes, through the runtime's own assembly (`Runtime::from_config`) on the fixture replay:
//! goals over Zenoh are off by default (a goal on `/abvs/gaze/goal` does nothing while the iceoryx2 goal
//! service works as before), on they are refused at start-up without authentication or access control
//! unless `insecure`, and with `insecure` a Zenoh peer's goal reaches the controller (so the test of "off"
//! can fail). Real Zenoh on loopback and real iceoryx2; a replay has no drive board, so a goal that reaches the
//! controller comes back refused as `no_board` (counted under its source).
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use abvs_runtime::bridges::iceoryx::gaze::{goal_service, GazeGoalWire};
use abvs_runtime::bridges::iceoryx::Ipc;
use abvs_runtime::shipped::shipped;
use abvs_runtime::Runtime;
use abvs_runtime_core::config::{EngineKind, RuntimeConfig};
use iceoryx2::prelude::*;
use zenoh::Wait;

fn small(prefix: &str) -> RuntimeConfig {
    let mut c = RuntimeConfig::for_session(shipped("fixtures/session"));
    c.disparity.width = 160;
    c.disparity.height = 120;
    c.disparity.engine = EngineKind::Sgbm;
    c.source.looping = true;
    c.source.seconds = Some(30.0);
    c.sinks.self_check.enabled = false;
    c.bridges.iceoryx.service_prefix = prefix.into();
    c
}

fn free_endpoint() -> String {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    format!("tcp/127.0.0.1:{}", l.local_addr().unwrap().port())
}

/// A geometry_msgs/msg/PointStamped in the left home camera frame, as CDR.
fn point_stamped(p: [f64; 3]) -> Vec<u8> {
    let frame = b"left_home_camera";
    let mut b = vec![0u8, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0];
    b.extend_from_slice(&(frame.len() as u32 + 1).to_le_bytes());
    b.extend_from_slice(frame);
    b.push(0);
    while (b.len() - 4) % 8 != 0 {
        b.push(0);
    }
    p.iter().for_each(|v| b.extend_from_slice(&v.to_le_bytes()));
    b
}

/// One replay with Zenoh listening on loopback: a Zenoh peer sends goals, an iceoryx2 process one goal; returns
/// the stats JSON and the last state the peer read on `/abvs/gaze/state`.
fn run_with_peers(mut c: RuntimeConfig) -> (serde_json::Value, serde_json::Value, String) {
    let endpoint = free_endpoint();
    c.bridges.zenoh.enabled = true;
    c.bridges.zenoh.listen = vec![endpoint.clone()];
    // loopback only: no multicast scouting of the other tests' sessions
    let dir = tempfile::tempdir().unwrap();
    let zc = dir.path().join("zenoh.json5");
    std::fs::write(&zc, "{ scouting: { multicast: { enabled: false } } }").unwrap();
    c.bridges.zenoh.config = Some(zc);
    let runtime = Runtime::from_config(&c).unwrap();
    let access = runtime.gaze_access().to_string();
    let cfg = abvs_runtime::bridges::iceoryx::BridgeConfig::for_deployment(&c);
    let handle = runtime.spawn().unwrap();

    let mut pc = zenoh::Config::default();
    pc.insert_json5("mode", "\"client\"").unwrap();
    pc.insert_json5("connect/endpoints", &serde_json::to_string(&[&endpoint]).unwrap()).unwrap();
    pc.insert_json5("scouting/multicast/enabled", "false").unwrap();
    let peer = zenoh::open(pc).wait().unwrap();
    let states = Arc::new(AtomicU64::new(0));
    let last = Arc::new(Mutex::new(serde_json::Value::Null));
    let (n, l) = (states.clone(), last.clone());
    let _sub = peer
        .declare_subscriber("abvs/gaze/state")
        .callback(move |s| {
            let b = s.payload().to_bytes();
            // std_msgs/msg/String: encapsulation, length (with the NUL), the text, NUL
            if let Ok(v) = serde_json::from_slice(&b[8..b.len() - 1]) {
                *l.lock().unwrap() = v;
            }
            n.fetch_add(1, Ordering::Relaxed);
        })
        .wait()
        .unwrap();
    let t = Instant::now();
    while states.load(Ordering::Relaxed) < 3 {
        assert!(t.elapsed() < Duration::from_secs(20), "no gaze state over Zenoh");
        std::thread::sleep(Duration::from_millis(10));
    }
    for i in 0..10 {
        peer.put("abvs/gaze/goal", point_stamped([0.0, 0.0, 0.5 + 0.05 * i as f64])).wait().unwrap();
        std::thread::sleep(Duration::from_millis(40));
    }
    // the iceoryx2 goal service as a robot process uses it
    let node = NodeBuilder::new().create::<Ipc>().unwrap();
    let publisher = goal_service(&node, &cfg).unwrap().publisher_builder().create().unwrap();
    let goal = GazeGoalWire { id: 777, kind: 1, point_m: [0.05, 0.0, 0.7], ..Default::default() };
    let gaze = handle.gaze();
    let t = Instant::now();
    while gaze.state().is_none_or(|s| s.goal_id != 777) {
        assert!(t.elapsed() < Duration::from_secs(20), "the iceoryx2 goal was not taken: {:?}", gaze.state());
        publisher.loan_uninit().unwrap().write_payload(goal).send().unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
    handle.stop();
    let j = handle.join().unwrap().json();
    let state = last.lock().unwrap().clone();
    (j, state, access)
}

#[test]
fn zenoh_goals_are_off_by_default_refused_without_security_and_iceoryx2_unaffected() {
    let t0 = Instant::now();
    let prefix = format!("abvs-test-access-{}", std::process::id());

    // on without authentication or access control: refused at start-up, by the key's name
    let mut c = small(&format!("{prefix}-a"));
    c.bridges.zenoh.accept_gaze_goals = true;
    let e = Runtime::from_config(&c).err().expect("refused").to_string();
    assert!(e.contains("bridges.zenoh.accept_gaze_goals") && e.contains("insecure"), "{e}");
    // the shipped access control is enough
    c.bridges.zenoh.config = Some(shipped("config/zenoh-gaze-acl.json5"));
    c.bridges.zenoh.listen = vec![free_endpoint()];
    let r = Runtime::from_config(&c).unwrap();
    assert!(r.gaze_access().contains("access control (deny by default)"), "{}", r.gaze_access());
    drop(r);

    // off (the default): Zenoh goals do nothing, the iceoryx2 goal is taken
    let (j, state, access) = run_with_peers(small(&format!("{prefix}-b")));
    eprintln!("{access}\n{}\n{}\n{state}", j["gaze"], j["gaze_zenoh"]);
    assert!(access.contains("over Zenoh: off"), "{access}");
    let g = &j["gaze"];
    assert_eq!(g["sources"]["zenoh"]["posted"], 0, "{g}");
    assert_eq!(j["gaze_zenoh"]["goals_received"], 0, "{j}");
    assert!(g["sources"]["iceoryx2"]["taken"].as_u64().unwrap() >= 1, "{g}");
    assert_eq!(g["refused"]["no_board"], g["goals"], "{g}");
    assert_eq!(state["source"], "iceoryx2", "{state}");

    // on and insecure (said at start-up): the same peer's goals reach the controller
    let mut c = small(&format!("{prefix}-c"));
    c.bridges.zenoh.accept_gaze_goals = true;
    c.bridges.zenoh.insecure = true;
    let (j, _, access) = run_with_peers(c);
    eprintln!("{access}\n{}\n{}", j["gaze"], j["gaze_zenoh"]);
    assert!(access.contains("INSECURE"), "{access}");
    let z = &j["gaze"]["sources"]["zenoh"];
    assert_eq!(j["gaze_zenoh"]["goals_posted"], 10, "{j}");
    assert_eq!(z["posted"], 10, "{z}");
    assert!(z["taken"].as_u64().unwrap() >= 1 && z["refused"] == z["taken"], "{z}");
    eprintln!("test wall time {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn the_documented_access_control_is_the_shipped_file() {
    let doc = std::fs::read_to_string(shipped("docs/gaze.md")).unwrap();
    let file = std::fs::read_to_string(shipped("config/zenoh-gaze-acl.json5")).unwrap();
    let start = doc.find("```json5\n").expect("docs/gaze.md shows the example") + "```json5\n".len();
    let end = start + doc[start..].find("```").unwrap();
    assert_eq!(&doc[start..end], file, "docs/gaze.md's block differs from config/zenoh-gaze-acl.json5");
}
