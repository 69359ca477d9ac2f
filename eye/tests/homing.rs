//! Start-up homing against a simulator of the drive board: from every start the home counts
//! come out exact within 180 deg + the tolerance of travel; bad streams are refused.
use abvs_eye::encoder::*;
use abvs_eye::error::EyeError;
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const N: i64 = COUNTS_PER_REV;
const TOL: i64 = DEFAULT_TOLERANCE_COUNTS;

/// The simulated drive board plus the decoder tolerance the check runs with.
#[derive(Clone, Debug)]
struct Board {
    start: [i64; 3],
    origin: [i64; 3],
    step: i64,
    noise: i64,
    width: i64,
    /// the decoder's tolerance (counts)
    tol: i64,
}

impl Board {
    fn roll(&self) -> StartupRoll {
        StartupRoll { start: self.start, origin: self.origin, step: self.step, noise: self.noise, width: self.width }
    }

    fn expected(&self, last: [i64; 3]) -> HomeCounts {
        self.roll().expected(last)
    }

    /// Runs homing to the end: (home, travel deg, counts of the deciding sample) or the error.
    fn run(&self, seed: u64) -> Result<(HomeCounts, f64, [i64; 3]), EyeError> {
        let mut h = Homing::with_tolerance_counts(self.tol);
        for s in self.roll().stream(seed).take((N / self.step) as usize) {
            if let HomingStatus::Done(home) = h.push(s)? {
                return Ok((home, h.travel_deg(), s.counts));
            }
        }
        panic!("homing never decided for {self:?} (travel {:.3} deg)", h.travel_deg());
    }

    fn check(&self, seed: u64) -> f64 {
        let (home, travel, last) = self.run(seed).unwrap_or_else(|e| panic!("{self:?}: {e}"));
        assert_eq!(home, self.expected(last), "{self:?}");
        let limit = 180.0 + counts_to_deg(self.tol, 0);
        assert!(travel <= limit, "{self:?}: travel {travel} > {limit}");
        travel
    }
}

fn deviation(rng: &mut ChaCha8Rng, tol: i64) -> [i64; 3] {
    // Pairwise within the tolerance; every few starts at the extremes.
    let h = tol / 2;
    match rng.gen_range(0..8) {
        0 => [-h, h, rng.gen_range(-h..=h)],
        1 => [h, rng.gen_range(-h..=h), -h],
        _ => [0; 3].map(|_| rng.gen_range(-h..=h)),
    }
}

/// `starts` start rolls evenly over the whole turn, with the decoder's tolerance `tol`.
fn sweep(starts: i64, tol: i64, seed: u64) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut worst: f64 = 0.0;
    for k in 0..starts {
        let t0 = deg_to_counts(k as f64 * 360.0 / starts as f64, 0);
        // Exact starts (on markers too) every 7th start, perturbed ones otherwise.
        let d = if k % 7 == 0 { [0; 3] } else { deviation(&mut rng, tol) };
        let board = Board {
            start: d.map(|x| t0 + x),
            origin: [0; 3].map(|_| rng.gen_range(-1_000_000_000i64..1_000_000_000)),
            step: [8, 13, 29, 64][(k % 4) as usize],
            noise: 2,
            width: 16,
            tol,
        };
        worst = worst.max(board.check(rng.gen()));
    }
    worst
}

/// Every 0.05 deg of start roll over the whole turn (7200 starts).
#[test]
fn every_start_homes_exactly_within_180_deg() {
    let worst = sweep(7200, TOL, 1);
    eprintln!("worst travel {worst:.3} deg");
}

/// The widest tolerance the decoder accepts (20 lines, ~5 deg) still decides exactly.
#[test]
fn widest_tolerance_still_homes_exactly() {
    sweep(720, 20 * COUNTS_PER_LINE, 2);
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 96,
        // Integration tests have no lib.rs next to them to persist failures beside.
        failure_persistence: None,
        ..ProptestConfig::default()
    })]
    #[test]
    fn random_starts_and_origins(
        t0 in 0i64..N,
        d in prop::array::uniform3(-(TOL / 2)..=TOL / 2),
        origin in prop::array::uniform3(prop_oneof![
            -5_000_000_000_000i64..5_000_000_000_000,
            -200_000i64..200_000,
            Just(i64::MIN / 4),
            Just(i64::MAX / 4)
        ]),
        step in 1i64..=96,
        noise in 0i64..=3,
        width in 1i64..=80,
        seed in any::<u64>(),
    ) {
        let board = Board { start: d.map(|x| t0 + x), origin, step, noise, width, tol: TOL };
        board.check(seed);
    }
}

fn stream(board: &Board, n: i64) -> Vec<HomingSample> {
    board.roll().stream(3).take(n as usize).collect()
}

fn plain(start_deg: f64) -> Board {
    let t = deg_to_counts(start_deg, 0);
    Board { start: [t, t + 40, t - 30], origin: [123_456, -7, 1 << 40], step: 16, noise: 1, width: 16, tol: TOL }
}

fn homing_err(r: abvs_eye::Result<HomeCounts>) -> String {
    match r {
        Err(EyeError::Homing(m)) => m,
        other => panic!("expected a homing error, got {other:?}"),
    }
}

#[test]
fn batch_homing_matches_the_board() {
    let b = plain(123.4);
    let s = stream(&b, N / b.step);
    let home = home_from_stream(&s).unwrap();
    // Re-find the deciding sample to get the representative.
    let mut h = Homing::new();
    let last = s.iter().find(|x| matches!(h.push(**x).unwrap(), HomingStatus::Done(_))).unwrap();
    assert_eq!(home, b.expected(last.counts));
    let th = home.theta_deg(last.counts);
    assert!(th.iter().all(|t| *t > -180.0 && *t <= 180.0));
}

#[test]
fn stream_that_stops_early_is_ambiguous() {
    // From 192 deg the first pulse is link 2 at 350.06 deg, a {2} that also happens at
    // 170.06; stop right after it.
    let b = plain(192.0);
    let s = stream(&b, deg_to_counts(165.0, 0) / b.step);
    let m = homing_err(home_from_stream(&s));
    assert!(m.contains("ambiguous") && m.contains("need more travel") && m.contains("link 2 at +157.9"), "{m}");
    // No pulse at all.
    let m = homing_err(home_from_stream(&s[..100]));
    assert!(m.contains("ambiguous: no index pulse after"), "{m}");
}

#[test]
fn spurious_pulse_is_refused() {
    // From 5 deg link 1 pulses at 9.94 deg; a second link-1 pulse at 60 deg fits no marker.
    let b = plain(5.0);
    let mut s = stream(&b, N / b.step);
    let k = deg_to_counts(55.0, 0) as usize / b.step as usize;
    s[k].index[0] = true;
    let m = homing_err(home_from_stream(&s));
    assert!(m.contains("link 1: index pulse at +54.9") && m.contains("no marker can be"), "{m}");
}

#[test]
fn missing_pulse_is_refused() {
    // From 5 deg: drop link 1's pulse at 180 deg (the second of its own).
    let b = plain(5.0);
    let mut s = stream(&b, N / b.step);
    for x in s.iter_mut().skip(deg_to_counts(100.0, 0) as usize / b.step as usize) {
        x.index[0] = false;
    }
    let m = homing_err(home_from_stream(&s));
    assert!(m.contains("no marker hypothesis fits") && m.contains("expected index pulse"), "{m}");
}

#[test]
fn start_angles_too_far_apart_are_refused() {
    // Link 2 starts 30 deg ahead of the others: its pulses cannot match theirs.
    let mut b = plain(100.0);
    b.start[1] += deg_to_counts(30.0, 0);
    let m = homing_err(home_from_stream(&stream(&b, N / b.step)));
    assert!(m.contains("no marker hypothesis fits") || m.contains("no decision"), "{m}");
}

#[test]
fn links_not_moving_together_are_refused() {
    let b = plain(40.0);
    let mut s = stream(&b, 2000);
    // Link 3 stalls after 20 deg.
    let k = deg_to_counts(20.0, 0) as usize / b.step as usize;
    let c = s[k].counts[2];
    for x in s.iter_mut().skip(k) {
        x.counts[2] = c;
    }
    let m = homing_err(home_from_stream(&s));
    assert!(m.contains("links do not move together"), "{m}");
}

#[test]
fn link_moving_backwards_is_refused() {
    let b = plain(40.0);
    let mut s = stream(&b, 400);
    s[300].counts[1] -= 200;
    let m = homing_err(home_from_stream(&s));
    assert!(m.contains("link 2 moved backwards"), "{m}");
    // Once failed, it stays failed.
    let mut h = Homing::new();
    let r: Vec<_> = s.iter().map(|x| h.push(*x).is_err()).collect();
    assert!(r[300] && r[301]);
}

#[test]
fn counts_and_degrees_round_trip() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for _ in 0..20_000 {
        let home = rng.gen_range(-1i64 << 45..1i64 << 45);
        let c = home + rng.gen_range(-10 * N..10 * N);
        assert_eq!(deg_to_counts(counts_to_deg(c, home), home), c);
    }
    assert_eq!(counts_to_deg(N / 2, 0), 180.0);
    assert_eq!(counts_to_deg(MARKER_COUNTS[1], 0), 360.0 * 2560.0 / 92672.0);
    assert_eq!(deg_to_counts(360.0, 5), N + 5);
    let q = quantize_deg(12.345);
    assert!((q - 12.345).abs() <= 0.5 * 360.0 / N as f64);
    assert_eq!(quantize_deg(q), q);
    assert_eq!(deg_to_counts(q, 0) as f64 * 360.0 / N as f64, q);
}
