//! Time alignment at saccade speed: link angles interpolated to each frame's mid-exposure time,
//! with the eye's encoder_time_offset applied, keep the pose error from timing below 0.02 deg.
use abvs_eye::encoder::quantize_deg;
use abvs_eye::pose::rotation_angle_deg;
use abvs_eye::{Fick, SpmGeometry, UnitModel};
use abvs_runtime::tasks::align::EncoderTrack;
use abvs_runtime_core::error::RuntimeError;
use abvs_runtime_core::messages::EncoderSample;

/// A minimum-jerk saccade from yaw -20 to +20 deg (pitch 10, roll 3) whose peak speed is the
/// paper's 1561 deg/s: peak of min-jerk = 1.875 A / T.
fn saccade(t: f64) -> [f64; 3] {
    let (a, peak) = (40.0, 1561.0);
    let dur = 1.875 * a / peak;
    let s = (t / dur).clamp(0.0, 1.0);
    let x = 10.0 * s.powi(3) - 15.0 * s.powi(4) + 6.0 * s.powi(5);
    [10.0, 3.0, -20.0 + a * x]
}

fn links(g: &SpmGeometry, t: f64) -> [f64; 3] {
    g.ik(&Fick::from_deg(saccade(t)).to_matrix()).unwrap().map(f64::to_degrees)
}

fn unit_with_latency(ms: f64) -> UnitModel {
    let mut u = UnitModel::nominal();
    u.effects.encoder_time_offset.enabled = true;
    u.effects.encoder_time_offset.latency_ms = ms;
    u
}

/// The drive board's 1 kHz stream: a sample stamped t_enc holds the (quantised) angles the links
/// had at camera time t_enc - latency.
fn stream(g: &SpmGeometry, latency_s: f64, track: &mut EncoderTrack) {
    for k in 0..200 {
        let t_enc = -0.05 + k as f64 * 1e-3;
        let th = links(g, t_enc - latency_s).map(quantize_deg);
        track.push(EncoderSample { t_s: t_enc, theta_deg: th }).unwrap();
    }
}

/// Worst rotation error (deg) over mid-exposure times every 0.37 ms across the saccade.
fn worst_error(g: &SpmGeometry, track: &EncoderTrack) -> f64 {
    let mut worst: f64 = 0.0;
    let mut t = -0.01;
    while t < 0.07 {
        let est = track.at_camera_time(t).unwrap().map(f64::to_radians);
        let truth = Fick::from_deg(saccade(t)).to_matrix();
        let r = g.fk_cold(&est).unwrap().r;
        worst = worst.max(rotation_angle_deg(&r, &truth));
        t += 0.37e-3;
    }
    worst
}

#[test]
fn saccade_at_1561_deg_per_s_stays_within_0_02_deg() {
    let g = SpmGeometry::nominal();
    let unit = unit_with_latency(2.0);
    let mut track = EncoderTrack::for_unit(500, &unit);
    assert!((track.latency_s - 0.002).abs() < 1e-12);
    stream(&g, 0.002, &mut track);
    let err = worst_error(&g, &track);
    assert!(err < 0.02, "worst timing error {err} deg");

    // Ignoring the 2 ms latency costs degrees at this speed: why the offset is in the unit model.
    let mut naive = EncoderTrack::new(500);
    stream(&g, 0.002, &mut naive);
    let naive_err = worst_error(&g, &naive);
    eprintln!("worst timing error {err:.5} deg with the latency applied, {naive_err:.3} deg ignoring it");
    assert!(naive_err > 1.0, "{naive_err}");
}

#[test]
fn bad_streams_are_refused_and_counted() {
    let mut track = EncoderTrack::new(8);
    track.push(EncoderSample { t_s: 1.0, theta_deg: [0.0; 3] }).unwrap();
    let e = track.push(EncoderSample { t_s: 1.0, theta_deg: [0.0; 3] }).unwrap_err();
    assert!(matches!(e, RuntimeError::NonMonotonic { .. }), "{e}");
    assert!(e.to_string().contains("encoder") && e.to_string().contains("1.000000"));
    assert_eq!(track.stats.non_monotonic, 1);
    let e = track.push(EncoderSample { t_s: f64::NAN, theta_deg: [0.0; 3] }).unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
    track.push(EncoderSample { t_s: 1.001, theta_deg: [1.0; 3] }).unwrap();
    // A dropped stretch of the stream: 20 ms without samples is not interpolated across.
    track.push(EncoderSample { t_s: 1.021, theta_deg: [2.0; 3] }).unwrap();
    let e = track.at_encoder_time(1.01).unwrap_err();
    assert!(matches!(e, RuntimeError::Gap { .. }), "{e}");
    // Frames older or newer than the buffer.
    assert!(matches!(track.at_encoder_time(0.5), Err(RuntimeError::OutOfSpan { .. })));
    assert!(matches!(track.at_encoder_time(2.0), Err(RuntimeError::OutOfSpan { .. })));
    // Inside a regular stretch the values are interpolated (exact at the samples).
    assert_eq!(track.at_encoder_time(1.001).unwrap(), [1.0; 3]);
    // The buffer is bounded: old samples go.
    for k in 0..20 {
        track.push(EncoderSample { t_s: 1.03 + k as f64 * 1e-3, theta_deg: [3.0; 3] }).unwrap();
    }
    assert_eq!(track.span().unwrap().0, 1.03 + 12.0 * 1e-3);
    assert_eq!(track.stats.accepted, 23);
}
