//! Independent check of `render_moving` against the binding time convention
//! (docs/spec/conventions.md, "Time"), written from the convention alone, not from the renderer:
//!
//! - a frame's `t_start` is the start of exposure of row 0 (the top row as stored);
//! - row r starts exposing at `t_start + r * readout / (H - 1)` and integrates for `exposure`,
//!   so its mid-exposure instant is `t_start + r * readout / (H - 1) + exposure / 2`;
//! - a frame's single instant is its middle row's mid-exposure.
//!
//! `render_moving` only receives a pose per (row, time sample), so the timing lives in the small
//! helper below ([`Shutter`]), which maps (row y, sample k) to
//! `t_start + y * readout / (H - 1) + (k + 0.5) / K * exposure`, and [`yaw_pose`], a yaw pursuit at
//! a known angular speed about the camera centre, identity at the frame instant.
//!
//! Scene: a fronto-parallel plane at z = 1 m, black for world x < 0 and white for x > 0 (one sharp
//! vertical edge through the optical axis at the frame instant), seen by an ideal pinhole
//! (`Camera::pinhole`, so the image scale at the centre is exactly fx px/rad).
//!
//! SIGN (derived from first principles, not from the code):
//! 1. Fick yaw gamma is a right-handed rotation about the camera's +y axis (down). Rotating +z by
//!    gamma about +y gives (sin gamma, 0, cos gamma) (since y x z = x): gamma > 0 turns the optical
//!    axis toward world +x, i.e. the camera pans to the right. With world_from_camera = Ry(gamma(t)),
//!    gamma(t) = omega * (t - t_frame), omega > 0 pans right over time.
//! 2. The world edge point (0, Y, 1) in the camera frame is Ry(-gamma) (0, Y, 1) = (-sin g, Y, cos g),
//!    so the pinhole puts it at u = cx - fx * tan(gamma): as the camera pans right, the world-fixed
//!    edge moves toward -x (left) in the image, for every Y (the edge stays vertical at any instant).
//! 3. Rolling shutter: row y is exposed at t_y = t_start + y * readout / (H - 1) + exposure / 2, later
//!    for larger y (further down the stored image), so gamma(t_y) grows with y and the edge sits
//!    further toward -x in lower rows: u(H-1) - u(0) = -2 fx tan(omega readout / 2) ~ -omega readout fx.
//!    The edge leans like '/': top to the right, bottom to the left. With readout = 0 it is vertical.
//! 4. Exposure blur: the K poses are spread evenly over [row start, row start + exposure], symmetric
//!    about mid-exposure, so the smear (length ~ omega * exposure * fx px) is centred where the
//!    instantaneous edge would be at mid-exposure: the same place as with a tiny exposure.

use abvs_camera::Camera;
use abvs_render::{render_moving, RayTable, RenderOptions, Rendered, Scene, Surface, Texture};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// Image size and focal length (px). Small so the test stays fast; the shear does not depend on H.
const W: u32 = 160;
const H: u32 = 120;
const F: f64 = 300.0;
/// Distance of the textured plane (m).
const PLANE_Z: f64 = 1.0;

/// Columns over which a row's edge is measured (pixel centres at integers; cx = 79.5): wide enough to
/// hold the whole transition (at most ~6 px either side of cx here) with dark/bright margins.
const WIN_LO: usize = 50;
const WIN_HI: usize = 109;
/// Plateaus outside the window giving each row's black and white levels.
const DARK_LO: usize = 36;
const DARK_HI: usize = 45;
const BRIGHT_LO: usize = 114;
const BRIGHT_HI: usize = 123;

/// Exposure timing of one frame, exactly as the convention states it (seconds).
#[derive(Clone, Copy, Debug)]
struct Shutter {
    /// Start of exposure of row 0.
    t_start: f64,
    /// First row's start of exposure to the last row's (0 = global shutter).
    readout: f64,
    /// Exposure time of every row.
    exposure: f64,
    /// Image height H (rows 0 .. H-1).
    height: usize,
    /// Time samples K per row.
    samples: usize,
}

impl Shutter {
    /// Start of exposure of row `y`: `t_start + y * readout / (H - 1)`.
    fn row_start(&self, y: usize) -> f64 {
        self.t_start + y as f64 * self.readout / (self.height - 1) as f64
    }

    /// Time of sample `k` of row `y`: the centre of the k-th of K equal slices of the row's exposure,
    /// `t_start + y * readout / (H - 1) + (k + 0.5) / K * exposure`.
    fn sample_time(&self, y: usize, k: usize) -> f64 {
        self.row_start(y) + (k as f64 + 0.5) / self.samples as f64 * self.exposure
    }

    /// Mid-exposure instant of row `y`.
    fn row_mid_exposure(&self, y: usize) -> f64 {
        self.row_start(y) + self.exposure / 2.0
    }

    /// The frame's single instant: the middle row's ((H - 1) / 2, possibly between two rows)
    /// mid-exposure, `t_start + readout / 2 + exposure / 2`.
    fn frame_instant(&self) -> f64 {
        self.t_start + 0.5 * self.readout + self.exposure / 2.0
    }
}

/// world_from_camera of a camera yawed by Fick yaw `gamma` (rad, about its own +y axis, down) about
/// its centre, the world being the camera frame at the frame instant.
fn yaw_pose(gamma: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::identity(), UnitQuaternion::from_axis_angle(&Vector3::y_axis(), gamma))
}

/// Yaw of the pursuit at time `t`: `omega` rad/s, zero at the frame instant.
fn pursuit_yaw(shutter: &Shutter, omega: f64, t: f64) -> f64 {
    omega * (t - shutter.frame_instant())
}

/// Where the camera model (not the renderer) puts the world edge at yaw `gamma`: column of the
/// projection of the edge point (0, 0, PLANE_Z).
fn predicted_edge_u(camera: &Camera, gamma: f64) -> f64 {
    let p = yaw_pose(gamma).inverse() * Point3::new(0.0, 0.0, PLANE_Z);
    camera.project(&p.coords).expect("edge point projects").x
}

/// A 4 m x 3 m plane at z = 1 m (the view spans only about +-0.27 x +-0.2 m there), black for
/// world x < 0 and white for x > 0. Texture u runs along local +x over the plane's width, so
/// u = 0.5 is world x = 0.
fn edge_scene() -> Scene {
    let texture = Texture::procedural(|u: f64, _v: f64| if u < 0.5 { 0.0 } else { 1.0 });
    let plane = Surface::rect_centred(Isometry3::translation(0.0, 0.0, PLANE_Z), 4.0, 3.0, texture).expect("plane");
    Scene::new(0.5).with(plane)
}

fn options() -> RenderOptions {
    RenderOptions { supersample: 4, keep_linear: true, ..RenderOptions::default() }
}

/// Renders the edge scene under the yaw pursuit `omega` with the timing of `shutter`.
fn render_pursuit(rays: &RayTable, shutter: Shutter, omega: f64) -> Rendered {
    assert_eq!(shutter.height, rays.height());
    let pose = move |y: usize, k: usize| {
        assert!(y < shutter.height && k < shutter.samples, "pose asked for row {y}, sample {k}");
        yaw_pose(pursuit_yaw(&shutter, omega, shutter.sample_time(y, k)))
    };
    render_moving(&edge_scene(), rays, &pose, shutter.samples, &options()).expect("render_moving")
}

/// The edge in one row.
#[derive(Clone, Copy, Debug)]
struct RowEdge {
    /// Mean edge position (px, pixel centres at integers) from the dark area: for a profile going
    /// from black to white, `(WIN_LO - 0.5) + sum (1 - q_i)` is exactly the mean of the edge
    /// positions it mixes (pixel box sampling integrates exactly), so it is unbiased for both a
    /// sharp and a motion-blurred edge.
    centre: f64,
    /// Distance between the 10% and 90% crossings (px), by linear interpolation between pixels.
    width_10_90: f64,
}

fn row_edges(img: &Rendered) -> Vec<RowEdge> {
    let lin = img.linear.as_ref().expect("keep_linear gives the linear image");
    assert_eq!(lin.len(), img.width * img.height);
    (0..img.height)
        .map(|y| {
            let row = &lin[y * img.width..(y + 1) * img.width];
            let plateau =
                |lo: usize, hi: usize| (lo..=hi).map(|i| f64::from(row[i])).sum::<f64>() / (hi - lo + 1) as f64;
            let dark = plateau(DARK_LO, DARK_HI);
            let bright = plateau(BRIGHT_LO, BRIGHT_HI);
            assert!(
                bright > dark && bright - dark > 0.5 * bright.abs(),
                "row {y}: no black-to-white edge (dark {dark}, bright {bright})"
            );
            let q = |i: usize| (f64::from(row[i]) - dark) / (bright - dark);
            assert!(q(WIN_LO) < 0.01 && q(WIN_HI) > 0.99, "row {y}: the edge is not inside the window");
            let centre = (WIN_LO as f64 - 0.5) + (WIN_LO..=WIN_HI).map(|i| 1.0 - q(i)).sum::<f64>();
            let crossing = |level: f64| {
                for i in WIN_LO + 1..=WIN_HI {
                    let (q0, q1) = (q(i - 1), q(i));
                    if q1 >= level {
                        return (i - 1) as f64 + (level - q0) / (q1 - q0);
                    }
                }
                panic!("row {y}: no {level} crossing");
            };
            RowEdge { centre, width_10_90: crossing(0.9) - crossing(0.1) }
        })
        .collect()
}

/// Least-squares line `x = a + b * y`: (b, a, largest |residual|).
fn fit_line(xs: &[f64]) -> (f64, f64, f64) {
    let n = xs.len() as f64;
    let ym = (xs.len() - 1) as f64 / 2.0;
    let xm = xs.iter().sum::<f64>() / n;
    let (mut sxy, mut syy) = (0.0, 0.0);
    for (y, x) in xs.iter().enumerate() {
        sxy += (y as f64 - ym) * (x - xm);
        syy += (y as f64 - ym).powi(2);
    }
    let b = sxy / syy;
    let a = xm - b * ym;
    let max_res = xs.iter().enumerate().map(|(y, x)| (x - a - b * y as f64).abs()).fold(0.0, f64::max);
    (b, a, max_res)
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n as f64
}

#[test]
fn the_helpers_follow_the_convention() {
    let s = Shutter { t_start: 2.0, readout: 0.030, exposure: 0.010, height: 121, samples: 4 };
    assert!((s.row_start(0) - 2.0).abs() < 1e-12);
    assert!((s.row_start(120) - 2.030).abs() < 1e-12);
    assert!((s.row_mid_exposure(60) - (2.015 + 0.005)).abs() < 1e-12);
    assert!((s.frame_instant() - s.row_mid_exposure(60)).abs() < 1e-12);
    // The K samples are centred on the row's mid-exposure and span its exposure.
    let ts: Vec<f64> = (0..4).map(|k| s.sample_time(7, k)).collect();
    assert!((mean(ts.iter().copied()) - s.row_mid_exposure(7)).abs() < 1e-12);
    assert!((ts[0] - (s.row_start(7) + 0.00125)).abs() < 1e-12);
    // Positive yaw turns the optical axis toward +x (a pan to the right).
    let axis = yaw_pose(0.1) * Vector3::z();
    assert!(axis.x > 0.09 && axis.z > 0.99);
    // The camera model agrees with the first-principles u = cx - fx tan(gamma).
    let camera = Camera::pinhole(W, H, F);
    for g in [-0.02, 0.0, 0.013] {
        let u = predicted_edge_u(&camera, g);
        assert!((u - (camera.cx - F * f64::tan(g))).abs() < 1e-9, "gamma {g}: u {u}");
    }
}

#[test]
fn rolling_shutter_shears_a_vertical_edge_as_the_convention_implies() {
    let camera = Camera::pinhole(W, H, F);
    let rays = RayTable::new(&camera).expect("ray table");
    let h = rays.height();
    let omega = 60f64.to_radians();
    let rolling = Shutter { t_start: 12.345, readout: 0.030, exposure: 1e-4, height: h, samples: 1 };

    let edges = row_edges(&render_pursuit(&rays, rolling, omega));
    let centres: Vec<f64> = edges.iter().map(|e| e.centre).collect();
    let (slope, _, max_res) = fit_line(&centres);
    let shear = slope * (h - 1) as f64;
    let expected = -omega * rolling.readout * F; // -9.42 px (see SIGN in the header)
    assert!(
        shear < 0.0,
        "the edge must lie further toward -x in later (lower) rows when the camera pans toward +x: \
         shear u(H-1) - u(0) = {shear:.3} px"
    );
    assert!(
        (shear - expected).abs() < 0.03 * expected.abs(),
        "shear {shear:.3} px, expected omega * readout * fx = {expected:.3} px"
    );
    assert!(max_res < 0.12, "edge position not linear in the row: largest residual {max_res:.3} px");
    // Row by row against the camera model at that row's mid-exposure: catches a row mix-up
    // (flipped, offset) and a pose taken at the wrong instant.
    for (y, c) in centres.iter().enumerate() {
        let u = predicted_edge_u(&camera, pursuit_yaw(&rolling, omega, rolling.row_mid_exposure(y)));
        assert!((c - u).abs() < 0.1, "row {y}: edge at {c:.3} px, the convention puts it at {u:.3} px");
    }

    // Global shutter: every row at the frame instant, yaw 0, the edge vertical through cx.
    let global = Shutter { readout: 0.0, ..rolling };
    let centres: Vec<f64> = row_edges(&render_pursuit(&rays, global, omega)).iter().map(|e| e.centre).collect();
    let (slope, _, _) = fit_line(&centres);
    let shear = slope * (h - 1) as f64;
    assert!(shear.abs() < 0.1, "readout 0 must give a vertical edge, shear {shear:.3} px");
    for (y, c) in centres.iter().enumerate() {
        assert!((c - camera.cx).abs() < 0.1, "readout 0, row {y}: edge at {c:.3} px, expected cx = {}", camera.cx);
    }
}

#[test]
fn row_y_gets_the_poses_of_row_y() {
    // Alternate rows yawed by +-5 px worth: a renderer mixing up rows (even by one) fails here,
    // where the gentle ramp of the rolling shutter test could hide it.
    let camera = Camera::pinhole(W, H, F);
    let rays = RayTable::new(&camera).expect("ray table");
    let gamma = |y: usize| if y.is_multiple_of(2) { 5.0 / F } else { -5.0 / F };
    let pose = move |y: usize, _k: usize| yaw_pose(gamma(y));
    let img = render_moving(&edge_scene(), &rays, &pose, 1, &options()).expect("render_moving");
    for (y, e) in row_edges(&img).iter().enumerate() {
        let u = predicted_edge_u(&camera, gamma(y));
        assert!((e.centre - u).abs() < 0.1, "row {y}: edge at {:.3} px, its pose puts it at {u:.3} px", e.centre);
    }
}

#[test]
fn exposure_blur_spans_the_exposure_and_is_centred_on_mid_exposure() {
    let camera = Camera::pinhole(W, H, F);
    let rays = RayTable::new(&camera).expect("ray table");
    let h = rays.height();
    let omega = 60f64.to_radians();
    let sharp = Shutter { t_start: 3.0, readout: 0.0, exposure: 1e-4, height: h, samples: 1 };
    let blurred = Shutter { exposure: 0.030, samples: 64, ..sharp };
    // Smear length: omega * exposure * fx = 9.42 px.
    let smear = omega * blurred.exposure * F;

    let sharp_edges = row_edges(&render_pursuit(&rays, sharp, omega));
    let blurred_edges = row_edges(&render_pursuit(&rays, blurred, omega));
    let sharp_centre = mean(sharp_edges.iter().map(|e| e.centre));
    let blurred_centre = mean(blurred_edges.iter().map(|e| e.centre));
    let sharp_width = mean(sharp_edges.iter().map(|e| e.width_10_90));
    let blurred_width = mean(blurred_edges.iter().map(|e| e.width_10_90));

    // Mid-exposure is the frame instant here (readout 0), where the yaw is 0: the edge at cx.
    assert!((sharp_centre - camera.cx).abs() < 0.05, "sharp edge at {sharp_centre:.3} px, expected cx = {}", camera.cx);
    assert!(sharp_width < 1.8, "a tiny exposure must leave the edge sharp: 10-90% width {sharp_width:.3} px");
    // A uniform smear of length L (L >= 5 px, so the 1 px pixel box only rounds its ends) has a
    // 10-90% width of 0.8 L; the tolerance also covers any correlation between the pixel's spatial
    // and time samples (at most +-0.8 px).
    assert!(
        (blurred_width - 0.8 * smear).abs() < 0.12 * smear,
        "10-90% width {blurred_width:.3} px, expected 0.8 * omega * exposure * fx = {:.3} px",
        0.8 * smear
    );
    // The smear is centred on mid-exposure: same place as the sharp edge (a blur starting or ending
    // there would move it by L / 2 = 4.7 px).
    assert!(
        (blurred_centre - sharp_centre).abs() < 0.05,
        "blurred edge centred at {blurred_centre:.3} px, sharp one at {sharp_centre:.3} px"
    );
    // Still vertical with readout 0.
    let centres: Vec<f64> = blurred_edges.iter().map(|e| e.centre).collect();
    let (slope, _, _) = fit_line(&centres);
    assert!((slope * (h - 1) as f64).abs() < 0.1, "readout 0 with blur must stay vertical");
}
