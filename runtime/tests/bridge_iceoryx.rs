//! The iceoryx2 bridge on real shared memory: round trip, late joiner, a subscriber that never reads, and a
//! publisher restarted after its process was killed.
use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use abvs_runtime::bridges::iceoryx::*;
use abvs_runtime_core::messages::monotonic_ns;

/// A service prefix no other test (in this or another process) uses.
fn unique_config(w: u32, h: u32) -> BridgeConfig {
    static N: AtomicU32 = AtomicU32::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    BridgeConfig::for_resolution(w, h).with_prefix(format!("abvs-test-{}-{}", std::process::id(), n))
}

fn header(seq: u64, w: u32, h: u32) -> FrameHeader {
    let mut hd = FrameHeader::new_left_home();
    hd.seq = seq;
    hd.t_frame_ns = monotonic_ns() - 5_000_000;
    hd.pose_left = [1.5, -2.25, 0.125, 10.0, -3.0, 2.5];
    hd.pose_right = [-1.0, 0.5, 3.0, 70.0, 1.0, -0.5];
    hd.intrinsics = [500.5, 501.25, 319.5, 239.75];
    hd.width = w;
    hd.height = h;
    hd.baseline_m = 0.065;
    hd.valid = 17;
    hd.flags = 0xA5;
    hd
}

fn point(i: usize) -> CloudPoint {
    CloudPoint { x: i as f32 * 0.001, y: -(i as f32) * 0.002, z: 1.0 + i as f32 * 1e-4, rgba: i as u32 ^ 0xFF00_FF00 }
}

#[test]
fn depth_and_cloud_round_trip_exactly() {
    let cfg = unique_config(64, 48);
    let mut dp = DepthPublisher::new(&cfg).unwrap();
    let mut cp = CloudPublisher::new(&cfg).unwrap();
    let mut ds = DepthSubscriber::new(&cfg).unwrap();
    let mut cs = CloudSubscriber::new(&cfg).unwrap();

    let hd = header(7, 64, 48);
    let n = dp
        .publish_depth(&hd, |d| {
            for i in 0..d.capacity() {
                d.push(if i % 5 == 0 { f32::NAN } else { i as f32 * 0.01 });
            }
        })
        .unwrap();
    assert_eq!(n, 1, "delivered to the one depth subscriber");
    let r = ds.wait(Duration::from_secs(2)).unwrap().expect("depth sample");
    let got = r.header();
    assert_eq!(got.seq, 7);
    assert_eq!(got.t_frame_ns, hd.t_frame_ns);
    assert!(got.t_publish_ns >= hd.t_frame_ns && got.t_publish_ns <= monotonic_ns());
    assert_eq!(got.frame_id_str(), "left_home_camera");
    assert_eq!(got.frame_id, hd.frame_id);
    assert_eq!(got.pose_left, hd.pose_left);
    assert_eq!(got.pose_right, hd.pose_right);
    assert_eq!(got.intrinsics, hd.intrinsics);
    assert_eq!((got.width, got.height, got.valid, got.flags), (64, 48, 17, 0xA5));
    assert_eq!(got.baseline_m, 0.065);
    assert_eq!(r.data().len(), 64 * 48);
    for (i, v) in r.data().iter().enumerate() {
        if i % 5 == 0 {
            assert!(v.is_nan());
        } else {
            assert_eq!(v.to_bits(), (i as f32 * 0.01).to_bits());
        }
    }
    drop(r);

    // a cloud with fewer points than n_max: only the written points arrive
    let hc = header(8, 64, 48);
    cp.publish_cloud(&hc, 1000, |pts| {
        for i in 0..600 {
            pts.push(point(i));
        }
    })
    .unwrap();
    // and one with the exact count
    cp.publish_cloud(&header(9, 64, 48), 3, |pts| {
        for i in 0..3 {
            pts.push(point(i + 100));
        }
    })
    .unwrap();
    let r = cs.wait(Duration::from_secs(2)).unwrap().expect("cloud sample");
    assert_eq!(r.header().seq, 8);
    assert_eq!(r.header().valid, 600, "valid = points written");
    assert_eq!(r.header().pose_left, hc.pose_left);
    assert_eq!(r.data().len(), 600);
    assert!(r.data().iter().enumerate().all(|(i, p)| *p == point(i)));
    let r2 = cs.wait(Duration::from_secs(2)).unwrap().expect("second cloud sample");
    assert_eq!(r2.header().seq, 9);
    assert_eq!(r2.data(), &[point(100), point(101), point(102)]);
    drop((r, r2));
    assert!(cs.wait(Duration::from_millis(50)).unwrap().is_none(), "nothing more");
    assert_eq!(cs.stats().received, 2);

    // too large: a clear error naming the service, not a panic
    let e = cp.publish_cloud(&hc, 64 * 48 + 1, |_| {}).unwrap_err();
    assert!(e.to_string().contains("/cloud") && e.to_string().contains("exceed"), "{e}");
    let e = dp.publish_depth(&header(1, 640, 480), |_| {}).unwrap_err();
    assert!(e.to_string().contains("/depth"), "{e}");
    assert_eq!(dp.stats().published, 1);
    assert_eq!(cp.stats().published, 2);
}

#[test]
fn late_joiner_gets_the_latest_sample() {
    let cfg = unique_config(32, 24);
    let mut cp = CloudPublisher::new(&cfg).unwrap();
    for seq in 0..5u64 {
        cp.publish_cloud(&header(seq, 32, 24), 10, |pts| {
            for i in 0..10 {
                pts.push(point(i + seq as usize));
            }
        })
        .unwrap();
    }
    assert_eq!(cp.stats().deliveries, 0, "no subscriber yet");
    let mut cs = CloudSubscriber::new(&cfg).unwrap();
    // the publisher's next send (or update_connections) hands the history to the late joiner
    cp.update_connections().unwrap();
    let r = cs.wait(Duration::from_secs(2)).unwrap().expect("history sample");
    assert_eq!(r.header().seq, 4, "history 1: the latest sample");
    assert_eq!(r.data()[0], point(4));
    drop(r);
    assert!(cs.wait(Duration::from_millis(50)).unwrap().is_none(), "only the latest");

    // a second late joiner, history delivered by the next send instead
    let mut cs2 = CloudSubscriber::new(&cfg).unwrap();
    cp.publish_cloud(&header(5, 32, 24), 1, |pts| {
        pts.push(point(5));
    })
    .unwrap();
    let a = cs2.wait(Duration::from_secs(2)).unwrap().expect("history");
    assert_eq!(a.header().seq, 4);
    drop(a);
    let b = cs2.wait(Duration::from_secs(2)).unwrap().expect("new sample");
    assert_eq!(b.header().seq, 5);
}

#[test]
fn a_subscriber_that_never_reads_does_not_block_the_publisher() {
    let cfg = unique_config(320, 240);
    let mut cp = CloudPublisher::new(&cfg).unwrap();
    let _idle = CloudSubscriber::new(&cfg).unwrap(); // never reads
    let mut reader = CloudSubscriber::new(&cfg).unwrap();
    // one that holds the maximum of borrowed samples forever
    let mut holder = CloudSubscriber::new(&cfg).unwrap();
    let mut held = Vec::new();
    let t0 = std::time::Instant::now();
    for seq in 0..1000u64 {
        let d = cp
            .publish_cloud(&header(seq, 320, 240), 76_800, |pts| {
                let n = 1000 + (seq as usize % 7) * 100;
                for i in 0..n {
                    pts.push(point(i));
                }
            })
            .unwrap();
        assert_eq!(d, 3, "delivered to all three subscribers at sample {seq}");
        if held.len() < 2 {
            held.push(holder.wait(Duration::from_secs(1)).unwrap().unwrap());
        }
        if seq % 3 == 0 {
            // the reader keeps up only now and then
            while let Some(r) = reader.try_receive().unwrap() {
                assert_eq!(r.data().len(), r.header().valid as usize);
            }
        }
    }
    let s = cp.stats();
    assert_eq!(s.published, 1000);
    assert_eq!((s.loan_failures, s.send_failures, s.notify_failures), (0, 0, 0), "{s:?}");
    assert!(t0.elapsed() < Duration::from_secs(60), "publishing took {:?}", t0.elapsed());
    // the slow reader saw the newest samples, and gaps (safe overflow dropped the older ones)
    let last = reader.wait(Duration::from_secs(1)).unwrap();
    if let Some(r) = last {
        assert!(r.header().seq >= 998);
    }
    assert!(reader.stats().seq_gaps > 0);
    assert_eq!(held[0].header().seq, 0);
}

#[test]
fn a_second_publisher_is_refused_with_a_clear_error() {
    let cfg = unique_config(8, 8);
    let _p = DepthPublisher::new(&cfg).unwrap();
    let e = DepthPublisher::new(&cfg).err().expect("max_publishers = 1");
    assert!(e.to_string().contains(&cfg.service_name("depth")), "{e}");
}

/// Run in a child process by `publisher_restart_after_kill`: publishes, then dies without cleaning up.
#[test]
fn crash_helper_publisher() {
    let Ok(prefix) = std::env::var("ABVS_BRIDGE_CRASH_PREFIX") else { return };
    let cfg = BridgeConfig::for_resolution(16, 16).with_prefix(prefix);
    let mut p = CloudPublisher::new(&cfg).unwrap();
    let mut s = CloudSubscriber::new(&cfg).unwrap();
    p.publish_cloud(&header(1, 16, 16), 1, |pts| {
        pts.push(point(1));
    })
    .unwrap();
    let _held = s.wait(Duration::from_secs(2)).unwrap().unwrap();
    std::process::abort();
}

#[test]
fn publisher_restart_after_kill() {
    let cfg = unique_config(16, 16);
    let out = Command::new(std::env::current_exe().unwrap())
        .args(["crash_helper_publisher", "--exact", "--nocapture", "--test-threads", "1"])
        .env("ABVS_BRIDGE_CRASH_PREFIX", &cfg.prefix)
        .output()
        .unwrap();
    assert!(!out.status.success(), "the helper must die: {out:?}");
    // the dead process still holds the only publisher slot (max_publishers 1) and a subscriber with a
    // borrowed sample; creating the new node removes them (iceoryx2 cleans dead nodes on node creation),
    // else this publisher would be refused
    let mut p = CloudPublisher::new(&cfg).expect("restart after a crash");
    let mut s = CloudSubscriber::new(&cfg).unwrap();
    p.publish_cloud(&header(2, 16, 16), 1, |pts| {
        pts.push(point(2));
    })
    .unwrap();
    let r = s.wait(Duration::from_secs(2)).unwrap().expect("sample after restart");
    assert_eq!(r.header().seq, 2);
    assert_eq!(r.data(), &[point(2)]);
}

#[test]
fn publishers_and_subscribers_can_move_to_a_pipeline_thread() {
    fn send<T: Send>() {}
    send::<DepthPublisher>();
    send::<CloudPublisher>();
    send::<CloudSubscriber>();
    send::<Received<CloudPoint>>();
}

#[test]
fn a_subscriber_may_start_first_and_a_mismatching_configuration_is_refused() {
    let cfg = unique_config(16, 8);
    // the subscriber creates the services with the shared configuration; the publisher opens them
    let mut ds = DepthSubscriber::new(&cfg).unwrap();
    let mut dp = DepthPublisher::new(&cfg).unwrap();
    let mut h = header(3, 16, 8);
    h.valid = 128;
    dp.publish_depth(&h, |d| {
        for _ in 0..d.capacity() {
            d.push(2.5);
        }
    })
    .unwrap();
    let r = ds.wait(Duration::from_secs(2)).unwrap().expect("sample");
    assert_eq!((r.header().seq, r.data().len()), (3, 128));
    assert!(r.data().iter().all(|&v| v == 2.5));
    drop(r);

    // an empty cloud is a valid sample too
    let mut cp = CloudPublisher::new(&cfg).unwrap();
    let mut cs = CloudSubscriber::new(&cfg).unwrap();
    cp.publish_cloud(&header(4, 16, 8), 0, |_| {}).unwrap();
    let r = cs.wait(Duration::from_secs(2)).unwrap().expect("empty cloud");
    assert_eq!((r.header().seq, r.header().valid, r.data().len()), (4, 0, 0));

    // a process built with other settings (more subscribers than the service was created for) fails clearly
    let other = BridgeConfig { max_subscribers: 16, ..cfg.clone() };
    let e = DepthSubscriber::new(&other).err().expect("mismatching configuration");
    let msg = e.to_string();
    assert!(msg.contains(&cfg.service_name("depth")) && msg.contains("BridgeConfig"), "{msg}");
}

#[test]
fn nothing_unwritten_is_ever_sent() {
    let cfg = unique_config(16, 8);
    let mut dp = DepthPublisher::new(&cfg).unwrap();
    let mut cp = CloudPublisher::new(&cfg).unwrap();
    let mut ds = DepthSubscriber::new(&cfg).unwrap();
    let mut cs = CloudSubscriber::new(&cfg).unwrap();
    // The misuse, `publish_cloud(&h, 100, |_| 100)`, does not compile any more (the count is the
    // writer's, not the closure's; see the compile_fail example on SampleWriter). Its nearest legal form,
    // a fill that writes nothing into 100 loaned points, sends no point and an all-NaN tail.
    cp.publish_cloud(&header(1, 16, 8), 100, |_| {}).unwrap();
    let r = cs.wait(Duration::from_secs(2)).unwrap().expect("cloud");
    assert_eq!((r.header().valid, r.data().len()), (0, 0), "valid = what the writer counted");
    drop(r);
    // a depth fill that writes half the map: the other half arrives as NaN, never as old shared memory
    dp.publish_depth(&header(2, 16, 8), |d| {
        for _ in 0..64 {
            d.push(1.5);
        }
    })
    .unwrap();
    let r = ds.wait(Duration::from_secs(2)).unwrap().expect("depth");
    assert_eq!(r.data().len(), 128);
    assert!(r.data()[..64].iter().all(|&v| v == 1.5));
    assert!(r.data()[64..].iter().all(|v| v.is_nan()), "{:?}", &r.data()[64..]);
    drop(r);
    // writing past the sample is refused and nothing is sent
    let e = cp
        .publish_cloud(&header(3, 16, 8), 3, |p| {
            for i in 0..4 {
                p.push(point(i));
            }
        })
        .unwrap_err();
    assert!(matches!(e, BridgeError::Overflow { capacity: 3, .. }), "{e}");
    let e = cp.publish_cloud(&header(4, 16, 8), 2, |p| p.extend_from_slice(&[point(0); 3])).unwrap_err();
    assert!(e.to_string().contains("/cloud") && e.to_string().contains("wrote past"), "{e}");
    // more points than the header's organised width x height: refused before loaning
    let e = cp.publish_cloud(&header(5, 4, 2), 9, |_| {}).unwrap_err();
    assert!(matches!(e, BridgeError::TooLarge { n: 9, max: 8, .. }), "{e}");
    assert!(cs.wait(Duration::from_millis(50)).unwrap().is_none(), "nothing sent by the refused calls");
    assert_eq!(cp.stats().published, 1);
}

#[test]
fn a_service_created_with_foreign_settings_is_refused() {
    let cfg = unique_config(16, 8);
    // another process got there first with room for a second publisher: opening it would let that process
    // publish next to the runtime, so neither side uses it
    let foreign = BridgeConfig { max_publishers: 2, history: 2, ..cfg.clone() };
    let _other = DepthSubscriber::new(&foreign).unwrap();
    for e in [DepthPublisher::new(&cfg).err().expect("foreign"), DepthSubscriber::new(&cfg).err().expect("foreign")] {
        let msg = e.to_string();
        assert!(matches!(e, BridgeError::Foreign { .. }), "{msg}");
        assert!(
            msg.contains(&cfg.service_name("depth"))
                && msg.contains("max_publishers 2 (expected 1)")
                && msg.contains("history 2 (expected 1)")
                && msg.contains("another process created it"),
            "{msg}"
        );
    }
    // the event service is checked too
    let cfg = unique_config(16, 8);
    let _other = CloudSubscriber::new(&BridgeConfig { max_subscribers: 9, ..cfg.clone() }).unwrap();
    let e = CloudSubscriber::new(&cfg).err().expect("foreign");
    assert!(e.to_string().contains("max_subscribers 9 (expected 8)"), "{e}");
}

#[test]
fn a_taken_publisher_slot_names_the_holder() {
    let cfg = unique_config(8, 8);
    let _p = CloudPublisher::new(&cfg).unwrap();
    let e = CloudPublisher::new(&cfg).err().expect("max_publishers = 1");
    let msg = e.to_string();
    assert!(matches!(e, BridgeError::PublisherTaken { .. }), "{msg}");
    assert!(
        msg.contains(&cfg.service_name("cloud"))
            && msg.contains("only publisher slot")
            && msg.contains(&format!("process {}", std::process::id())),
        "{msg}"
    );
}

/// A publisher outside the bridge's API (raw iceoryx2 on the same service) sends payloads that do not fit
/// their headers: the subscriber drops and counts them, and hands out the good one after them.
#[test]
fn subscribers_drop_payloads_that_do_not_fit_their_header() {
    use iceoryx2::prelude::*;
    let cfg = unique_config(16, 8);
    let mut ds = DepthSubscriber::new(&cfg).unwrap();
    let node = NodeBuilder::new().signal_handling_mode(SignalHandlingMode::Disabled).create::<Ipc>().unwrap();
    let open = |topic: &str| {
        let name = ServiceName::new(&cfg.service_name(topic)).unwrap();
        node.service_builder(&name)
            .publish_subscribe::<[f32]>()
            .user_header::<FrameHeader>()
            .max_publishers(cfg.max_publishers)
            .max_subscribers(cfg.max_subscribers)
            .subscriber_max_buffer_size(cfg.subscriber_buffer)
            .subscriber_max_borrowed_samples(cfg.subscriber_max_borrowed)
            .history_size(cfg.history)
            .enable_safe_overflow(true)
            .max_nodes(cfg.max_nodes)
            .open()
            .unwrap()
    };
    let depth = open("depth");
    let raw = depth.publisher_builder().initial_max_slice_len(256).create().unwrap();
    let send = |len: usize, w: u32, h: u32, valid: u32, seq: u64| {
        let mut s = raw.loan_slice(len).unwrap();
        let uh = s.user_header_mut();
        (uh.width, uh.height, uh.valid, uh.seq) = (w, h, valid, seq);
        for v in s.payload_mut().iter_mut() {
            *v = 3.0;
        }
        s.send().unwrap();
    };
    // 200 values for a 16x8 map; more valid pixels than values; width x height beyond usize on 32 bits and
    // any real map (65536 x 65536 with 128 values)
    for (i, (len, w, h, valid)) in [(200, 16, 8, 0), (128, 16, 8, 129), (128, 65536, 65536, 0)].into_iter().enumerate()
    {
        send(len, w, h, valid, i as u64);
        assert!(ds.try_receive().unwrap().is_none(), "malformed sample {i} handed out");
        assert_eq!(ds.stats().malformed, i as u64 + 1);
    }
    send(128, 16, 8, 100, 7);
    let r = ds.wait(Duration::from_secs(2)).unwrap().expect("the good sample");
    assert_eq!((r.header().seq, r.data().len()), (7, 128));
    drop(r);
    assert_eq!((ds.stats().received, ds.stats().malformed), (1, 3));

    // the rule for both payloads (a cloud: at least `valid`, at most width x height points)
    let mut h = FrameHeader { width: 4, height: 2, valid: 3, ..Default::default() };
    assert!(payload_fits::<CloudPoint>(&h, 3) && payload_fits::<CloudPoint>(&h, 8));
    assert!(!payload_fits::<CloudPoint>(&h, 2), "fewer points than valid");
    assert!(!payload_fits::<CloudPoint>(&h, 9), "more points than width x height");
    assert!(payload_fits::<f32>(&h, 8) && !payload_fits::<f32>(&h, 7));
    h.valid = 9;
    assert!(!payload_fits::<f32>(&h, 8));
}

#[test]
fn a_publisher_that_does_not_fit_in_dev_shm_is_refused_up_front() {
    // 65535 x 65535 points: terabytes of samples, more than any /dev/shm holds. Its segment would be created
    // (sparse) and the process killed by SIGBUS at the first write that finds no free page; instead:
    let cfg = unique_config(65535, 65535);
    let e = CloudPublisher::new(&cfg).err().expect("refused").to_string();
    assert!(e.contains(&cfg.service_name("cloud")) && e.contains("/dev/shm") && e.contains("MB free"), "{e}");
    // the real sizes fit
    let small = unique_config(320, 240);
    let needed = small.publisher_bytes::<CloudPoint>() + small.publisher_bytes::<f32>();
    let free = abvs_runtime::bridges::iceoryx::free_bytes(std::path::Path::new("/dev/shm")).unwrap();
    assert!(needed < free, "{needed} B needed at 320x240, {free} B free in /dev/shm");
    assert!(CloudPublisher::new(&small).is_ok());
}
