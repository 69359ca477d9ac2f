//! End-to-end checks of the renderer against the camera model and analytic geometry.

use std::sync::Arc;

use abvs_camera::{Camera, Distortion};
use abvs_render::{
    render, render_with_rays, Filter, RayTable, RenderError, RenderOptions, Rendered, Scene, Surface, Texture,
};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};

fn pinhole(w: u32, h: u32, f: f64) -> Camera {
    Camera {
        width: w,
        height: h,
        fx: f,
        fy: f,
        cx: (w as f64 - 1.0) / 2.0,
        cy: (h as f64 - 1.0) / 2.0,
        distortion: Distortion::None,
    }
}

fn fisheye() -> Camera {
    Camera::ov8856()
}

fn pose(rx: f64, ry: f64, rz: f64, t: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(rx.to_radians(), ry.to_radians(), rz.to_radians()),
    )
}

/// Depth of every pixel equals d for a plane at distance d facing the camera, whatever the
/// camera pose and the lens.
#[test]
fn fronto_parallel_plane_depth_is_exact() {
    for (camera, name) in [(pinhole(320, 240, 300.0), "pinhole"), (fisheye().scaled(400, 300), "fisheye")] {
        for (world_from_camera, d) in [(Isometry3::identity(), 1.5), (pose(10.0, -25.0, 40.0, [0.3, -0.2, 1.0]), 0.37)]
        {
            let plane = world_from_camera * Isometry3::translation(0.0, 0.0, d);
            let scene = Scene::new(0.0).with(Surface::rect_centred(plane, 40.0, 40.0, Texture::constant(0.5)).unwrap());
            let r = render(&scene, &camera, &world_from_camera, &RenderOptions::default()).unwrap();
            let worst = r.depth.iter().map(|&z| ((z as f64 - d) / d).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-6, "{name}: worst relative depth error {worst:e}");
            assert!(r.gray.iter().all(|&g| g == 128), "{name}: gray");
        }
    }
}

/// Pixel-centre ray of `camera` (exact, f64), independent of the ray table.
fn ray(camera: &Camera, x: usize, y: usize) -> Option<Vector3<f64>> {
    camera.unproject(&Vector2::new(x as f64, y as f64))
}

#[test]
fn box_depth_matches_analytic() {
    let camera = pinhole(320, 240, 250.0);
    // A cube rotated 45 deg about y: the centre ray hits its front vertical edge.
    let (c, h) = (1.0, 0.2);
    let world_from_box = pose(0.0, 45.0, 0.0, [0.0, 0.0, c]);
    let scene =
        Scene::new(0.0).with(Surface::cuboid(world_from_box, Vector3::new(h, h, h), Texture::constant(1.0)).unwrap());
    let r = render(&scene, &camera, &Isometry3::identity(), &RenderOptions::default()).unwrap();
    let table = RayTable::new(&camera).unwrap();
    // Pixel centre (159.5, 119.5) is between pixels: check the 4 around it against the edge
    // distance, and every hit pixel lies on the box surface.
    let edge = c - h * 2f64.sqrt();
    let mut hits = 0;
    for y in 0..240 {
        for x in 0..320 {
            let z = r.depth[y * 320 + x] as f64;
            let d = table.centre_ray(x, y).unwrap().normalize();
            // Independent slab test in the box frame.
            let (o_l, d_l) = (world_from_box.inverse() * Point3::origin(), world_from_box.inverse() * d);
            let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
            for a in 0..3 {
                let (ta, tb) = ((-h - o_l[a]) / d_l[a], (h - o_l[a]) / d_l[a]);
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
            if t0 <= t1 && t0 > 0.0 {
                hits += 1;
                let expect = t0 * d.z;
                assert!((z - expect).abs() < 1e-6 * expect, "pixel ({x},{y}): depth {z} vs analytic {expect}");
            } else {
                assert!(z.is_infinite(), "pixel ({x},{y}) should miss, depth {z}");
            }
        }
    }
    assert!(hits > 5000);
    let centre = (r.depth[119 * 320 + 159] + r.depth[120 * 320 + 160]) as f64 / 2.0;
    assert!((centre - edge).abs() < 2e-3, "edge depth {centre} vs {edge}");
}

#[test]
fn sphere_depth_matches_analytic() {
    let camera = fisheye().scaled(400, 300);
    let (c, radius) = (Point3::new(0.4, -0.1, 0.8), 0.25);
    let world_from_camera = pose(0.0, 5.0, 0.0, [0.05, 0.0, 0.0]);
    let scene = Scene::new(0.0).with(Surface::sphere(c, radius, Texture::constant(1.0)).unwrap());
    let r = render(&scene, &camera, &world_from_camera, &RenderOptions::default()).unwrap();
    // The rays the renderer casts (f32 in the table: they differ from the camera's f64 rays by
    // ~1e-7 rad, which near the silhouette would dominate a 1e-6 depth comparison).
    let table = RayTable::new(&camera).unwrap();
    let c_cam = world_from_camera.inverse() * c;
    let mut hits = 0;
    let mut worst = 0.0f64;
    for y in 0..300 {
        for x in 0..400 {
            let Some(d) = table.centre_ray(x, y) else { continue };
            let d = d.normalize();
            let z = r.depth[y * 400 + x] as f64;
            let b = d.dot(&c_cam.coords);
            let disc = b * b - (c_cam.coords.norm_squared() - radius * radius);
            if disc > 1e-6 {
                hits += 1;
                let expect = (b - disc.sqrt()) * d.z;
                worst = worst.max(((z - expect) / expect).abs());
            } else if disc < -1e-6 {
                assert!(z.is_infinite(), "pixel ({x},{y}) should miss");
            }
        }
    }
    assert!(hits > 2000, "{hits} hits");
    assert!(worst < 1e-6, "worst relative sphere depth error {worst:e}");
}

#[test]
fn nearer_surface_occludes_whatever_the_order() {
    let camera = pinhole(200, 150, 150.0);
    let near = Surface::rect_centred(Isometry3::translation(0.0, 0.0, 0.6), 0.2, 0.2, Texture::constant(1.0)).unwrap();
    let far = Surface::rect_centred(Isometry3::translation(0.0, 0.0, 1.2), 3.0, 3.0, Texture::constant(0.2)).unwrap();
    let ball = Surface::sphere(Point3::new(0.3, 0.0, 1.0), 0.1, Texture::constant(0.6)).unwrap();
    let mut a: Option<Rendered> = None;
    for surfaces in [vec![near.clone(), far.clone(), ball.clone()], vec![far, ball, near]] {
        let scene = Scene { surfaces, background: 0.0 };
        let r = render(&scene, &camera, &Isometry3::identity(), &RenderOptions::default()).unwrap();
        let centre = 75 * 200 + 100;
        assert_eq!(r.gray[centre], 255);
        assert!((r.depth[centre] - 0.6).abs() < 1e-6);
        assert_eq!(r.gray[75 * 200 + 5], 51);
        assert!((r.depth[75 * 200 + 5] - 1.2).abs() < 1e-6);
        // The ball (in front of the far plane) at its projected centre.
        let px = camera.project(&Vector3::new(0.3, 0.0, 1.0)).unwrap();
        let k = px.y.round() as usize * 200 + px.x.round() as usize;
        assert_eq!(r.gray[k], 153);
        assert!(r.depth[k] > 0.89 && r.depth[k] < 0.91);
        if let Some(a) = &a {
            assert_eq!(a, &r);
        }
        a = Some(r);
    }
}

/// Intensity centroid of `img` in a (2 rad + 1)^2 window centred on the pixel nearest `at`.
fn centroid(img: &[f32], w: usize, at: Vector2<f64>, rad: isize) -> Vector2<f64> {
    let (cx, cy) = (at.x.round() as isize, at.y.round() as isize);
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for y in cy - rad..=cy + rad {
        for x in cx - rad..=cx + rad {
            let v = img[y as usize * w + x as usize] as f64;
            s += v;
            sx += v * x as f64;
            sy += v * y as f64;
        }
    }
    Vector2::new(sx / s, sy / s)
}

/// Small Gaussian blobs on a board (procedural texture, exact): the centroid of each blob's
/// image lands where `Camera::project` puts its centre, through pinhole and fisheye, on a tilted
/// board. Returns the worst error in pixels.
fn blob_error(camera: &Camera, world_from_camera: &Isometry3<f64>, board: Isometry3<f64>) -> f64 {
    let (bw, bh, sigma) = (0.8, 0.6, 0.004);
    let centres: Vec<(f64, f64)> =
        (0..5).flat_map(|i| (0..4).map(move |j| (0.1 + 0.15 * i as f64, 0.075 + 0.15 * j as f64))).collect();
    let blobs = centres.clone();
    let tex = Texture::procedural(move |u, v| {
        let (x, y) = (u * bw, v * bh);
        blobs.iter().map(|(bx, by)| (-((x - bx).powi(2) + (y - by).powi(2)) / (2.0 * sigma * sigma)).exp()).sum::<f64>()
            as f32
    });
    let scene = Scene::new(0.0).with(Surface::rect(board, bw, bh, tex).unwrap());
    let opts = RenderOptions { supersample: 4, keep_linear: true, ..Default::default() };
    let r = render(&scene, camera, world_from_camera, &opts).unwrap();
    let img = r.linear.unwrap();
    let camera_from_world = world_from_camera.inverse();
    let mut worst = 0.0f64;
    for (bx, by) in centres {
        let p = camera_from_world * (board * Point3::new(bx, by, 0.0));
        let px = camera.project(&p.coords).unwrap();
        let c = centroid(&img, r.width, px, 12);
        worst = worst.max((c - px).norm());
    }
    worst
}

#[test]
fn blob_centroids_land_on_projections() {
    let board = pose(0.0, 30.0, 10.0, [-0.5, -0.3, 1.4]);
    let pin = blob_error(&pinhole(640, 480, 600.0), &Isometry3::identity(), board);
    // Fisheye: board well off-axis (field angles up to ~50 deg), camera turned.
    let cam_pose = pose(5.0, -20.0, 3.0, [0.0, 0.0, 0.0]);
    let fish = blob_error(&fisheye(), &cam_pose, board);
    eprintln!("blob centroid error: pinhole {pin:.4} px, fisheye {fish:.4} px");
    assert!(pin < 0.02, "pinhole blob error {pin} px");
    assert!(fish < 0.02, "fisheye blob error {fish} px");
}

/// Sub-pixel saddle point (cornerSubPix's criterion: image gradients are orthogonal to
/// p - corner), iterated from `start`. An X-junction is point-symmetric about its centre, so the
/// fixed point is unbiased as long as the Gaussian weight (sigma 3 px) has decayed at the window's
/// border (12 px): a tighter window biases it by up to ~0.1 px.
fn refine_corner(img: &[f32], w: usize, start: Vector2<f64>) -> Vector2<f64> {
    let at = |x: isize, y: isize| img[y as usize * w + x as usize] as f64;
    let (rad, sigma) = (12isize, 3.0);
    let mut q = start;
    for _ in 0..50 {
        let (cx, cy) = (q.x.round() as isize, q.y.round() as isize);
        let (mut a, mut b) = (nalgebra::Matrix2::<f64>::zeros(), Vector2::<f64>::zeros());
        for y in cy - rad..=cy + rad {
            for x in cx - rad..=cx + rad {
                let g = Vector2::new(at(x + 1, y) - at(x - 1, y), at(x, y + 1) - at(x, y - 1));
                let r = Vector2::new(x as f64, y as f64) - q;
                let gg = g * g.transpose() * (-r.norm_squared() / (2.0 * sigma * sigma)).exp();
                a += gg;
                b += gg * r;
            }
        }
        let step = a.try_inverse().unwrap() * b;
        q += step;
        if step.norm() < 1e-7 {
            break;
        }
    }
    q
}

/// A sharp (nearest-texel) checkerboard, 8x8 supersampled and blurred (sigma 1 px): every inner
/// corner located by the saddle criterion lies within 0.05 px of `Camera::project`. (4x4 gives
/// ~0.08 px worst, 16x16 ~0.035: the rest is per-pixel sampling noise and the detector.)
fn checker_error(camera: &Camera, world_from_camera: &Isometry3<f64>, board: Isometry3<f64>) -> f64 {
    let (cols, rows, s) = (9, 7, 0.06);
    let tex = Texture::checkerboard(cols, rows).unwrap();
    let scene = Scene::new(0.5).with(Surface::rect(board, cols as f64 * s, rows as f64 * s, tex).unwrap());
    let opts = RenderOptions { supersample: 8, blur_sigma: 1.0, keep_linear: true, ..Default::default() };
    let r = render(&scene, camera, world_from_camera, &opts).unwrap();
    let img = r.linear.unwrap();
    let camera_from_world = world_from_camera.inverse();
    let mut worst = 0.0f64;
    for i in 1..cols {
        for j in 1..rows {
            let p = camera_from_world * (board * Point3::new(i as f64 * s, j as f64 * s, 0.0));
            let px = camera.project(&p.coords).unwrap();
            let found = refine_corner(&img, r.width, px + Vector2::new(0.4, -0.3));
            worst = worst.max((found - px).norm());
        }
    }
    worst
}

#[test]
fn checkerboard_corners_land_on_projections() {
    let board = pose(0.0, 25.0, 5.0, [-0.25, -0.2, 1.5]);
    let pin = checker_error(&pinhole(800, 600, 700.0), &Isometry3::identity(), board);
    let fish = checker_error(&fisheye(), &pose(0.0, -15.0, 0.0, [0.0, 0.0, 0.0]), board);
    eprintln!("checkerboard corner error: pinhole {pin:.4} px, fisheye {fish:.4} px");
    assert!(pin < 0.05, "pinhole corner error {pin} px");
    assert!(fish < 0.05, "fisheye corner error {fish} px");
}

/// The ray table's linearised sub-pixel rays reproject onto their sub-pixel positions.
#[test]
fn ray_table_subpixel_rays_are_accurate() {
    let camera = fisheye();
    let table = RayTable::new(&camera).unwrap();
    let mut worst = 0.0f64;
    for y in (0..1200).step_by(37) {
        for x in (0..1600).step_by(41) {
            for (dx, dy) in [(-0.5, -0.5), (0.5, 0.5), (0.375, -0.125), (-0.25, 0.5), (0.0, 0.0)] {
                let Some(r) = table.ray(x, y, dx, dy) else { continue };
                let Some(px) = camera.project(&r) else { continue };
                worst = worst.max((px - Vector2::new(x as f64 + dx, y as f64 + dy)).norm());
            }
        }
    }
    eprintln!("ray table worst sub-pixel error {worst:.2e} px");
    assert!(worst < 2e-3, "ray table sub-pixel error {worst} px");
}

fn textured_scene() -> Scene {
    let tex = Arc::new(Texture::from_texel_fn(64, 64, |i, j| ((i * 7 + j * 13) % 17) as f32 / 16.0).unwrap());
    Scene::new(0.1)
        .with(Surface::rect_centred(pose(0.0, 20.0, 0.0, [0.0, 0.0, 1.0]), 1.0, 1.0, tex.clone()).unwrap())
        .with(Surface::cuboid(pose(10.0, 30.0, 0.0, [0.2, 0.1, 0.7]), Vector3::new(0.1, 0.05, 0.08), tex).unwrap())
}

#[test]
fn same_seed_same_bytes_other_seed_other_noise() {
    let camera = pinhole(160, 120, 120.0);
    let scene = textured_scene();
    let opts = RenderOptions {
        supersample: 2,
        blur_sigma: 0.8,
        gain: 0.8,
        offset: 20.0,
        noise_sigma: 2.0,
        seed: 7,
        ..Default::default()
    };
    let a = render(&scene, &camera, &Isometry3::identity(), &opts).unwrap();
    let b = render(&scene, &camera, &Isometry3::identity(), &RenderOptions { threads: 1, ..opts.clone() }).unwrap();
    assert_eq!(a, b, "same seed, different thread count");
    let c = render(&scene, &camera, &Isometry3::identity(), &RenderOptions { seed: 8, ..opts.clone() }).unwrap();
    let differ = a.gray.iter().zip(&c.gray).filter(|(x, y)| x != y).count();
    assert!(differ > a.gray.len() / 2, "only {differ} pixels differ with another seed");
    assert_eq!(a.depth, c.depth);
    // The noise has the requested sigma (difference of two independent draws: sqrt(2) sigma).
    let quiet = render(&scene, &camera, &Isometry3::identity(), &RenderOptions { noise_sigma: 0.0, ..opts }).unwrap();
    let n = a.gray.len() as f64;
    let var = a.gray.iter().zip(&quiet.gray).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>() / n;
    assert!((var.sqrt() - 2.0).abs() < 0.15, "noise sigma {}", var.sqrt());
}

#[test]
fn photometry_gain_offset_vignetting() {
    let camera = fisheye().scaled(400, 300);
    let scene = Scene::new(0.5);
    let opts = RenderOptions { gain: 1.2, offset: 10.0, ..Default::default() };
    let r = render(&scene, &camera, &Isometry3::identity(), &opts).unwrap();
    assert!(r.gray.iter().all(|&g| g == 163), "0.5 * 1.2 * 255 + 10 = 163");
    assert!(r.depth.iter().all(|d| d.is_infinite()));
    let opts = RenderOptions { vignetting: 1.0, keep_linear: true, ..Default::default() };
    let r = render(&scene, &camera, &Isometry3::identity(), &opts).unwrap();
    let lin = r.linear.unwrap();
    for (x, y) in [(0, 150), (100, 40), (399, 299)] {
        let d = ray(&camera, x, y).unwrap();
        let expect = 127.5 * d.z.powi(4);
        assert!((lin[y * 400 + x] as f64 - expect).abs() < 1e-3, "vignetting at ({x},{y})");
    }
}

#[test]
fn rgb_textures_from_files_render_in_colour() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("red_blue.png");
    let mut img = image::RgbImage::new(2, 1);
    img.put_pixel(0, 0, image::Rgb([255, 0, 0]));
    img.put_pixel(1, 0, image::Rgb([0, 0, 255]));
    img.save(&path).unwrap();
    let tex = Texture::from_file(&path).unwrap().with_filter(Filter::Nearest);
    assert!(tex.is_rgb());
    let camera = pinhole(100, 50, 100.0);
    let scene =
        Scene::new(0.0).with(Surface::rect_centred(Isometry3::translation(0.0, 0.0, 1.0), 2.0, 2.0, tex).unwrap());
    let r = render(&scene, &camera, &Isometry3::identity(), &RenderOptions::default()).unwrap();
    let rgb = r.rgb.as_ref().unwrap();
    let (left, right) = (25 * 100 + 10, 25 * 100 + 90);
    assert_eq!(&rgb[3 * left..3 * left + 3], &[255, 0, 0]);
    assert_eq!(&rgb[3 * right..3 * right + 3], &[0, 0, 255]);
    assert_eq!(r.gray[left], 76); // luma of pure red
    assert_eq!(r.gray[right], 29);
    assert!(r.gray_image().save(dir.path().join("out.png")).is_ok());
}

#[test]
fn metric_texture_tiles_at_its_physical_size() {
    // A 2-texel stripe texture spanning 0.1 m, on a 1 m wide plane: 10 periods.
    let tex = Texture::from_texel_fn(2, 1, |i, _| i as f32).unwrap().with_filter(Filter::Nearest);
    let tex = tex.with_metric_size(0.1, 0.1).unwrap();
    let camera = pinhole(1000, 10, 1000.0);
    let scene = Scene::new(0.5).with(Surface::rect(Isometry3::translation(-0.5, -0.5, 1.0), 1.0, 1.0, tex).unwrap());
    let r = render(&scene, &camera, &Isometry3::identity(), &RenderOptions::default()).unwrap();
    let row = &r.gray[5 * 1000..6 * 1000];
    let transitions = row.windows(2).filter(|p| p[0] != p[1]).count();
    assert_eq!(transitions, 19);
}

#[test]
fn bad_input_is_reported() {
    let err = Texture::from_file("/nonexistent/board_a7.png").unwrap_err();
    assert!(matches!(err, RenderError::TextureFile { .. }));
    assert!(err.to_string().contains("/nonexistent/board_a7.png"), "{err}");
    let err = Surface::rect(Isometry3::identity(), 0.0, 1.0, Texture::constant(1.0)).unwrap_err();
    assert!(matches!(err, RenderError::InvalidSurface { .. }), "{err}");
    let err = Surface::sphere(Point3::origin(), -1.0, Texture::constant(1.0)).unwrap_err();
    assert!(err.to_string().contains("radius"), "{err}");
    assert!(Surface::cuboid(Isometry3::identity(), Vector3::new(1.0, f64::NAN, 1.0), Texture::constant(1.0)).is_err());
    assert!(matches!(Texture::from_gray(3, 2, vec![0.0; 5]), Err(RenderError::InvalidTexture(_))));
    assert!(matches!(Texture::from_gray(0, 2, vec![]), Err(RenderError::InvalidTexture(_))));
    // A surface built by hand is checked at render time, with its index.
    let scene = Scene::new(0.0)
        .with(Surface::sphere(Point3::new(0.0, 0.0, 2.0), 0.1, Texture::constant(1.0)).unwrap())
        .with(Surface::Rect {
            world_from_local: Isometry3::identity(),
            size: [1.0, 0.0],
            texture: Arc::new(Texture::constant(1.0)),
        });
    let camera = pinhole(10, 10, 10.0);
    let err = render(&scene, &camera, &Isometry3::identity(), &RenderOptions::default()).unwrap_err();
    assert!(err.to_string().contains("#1"), "{err}");
    let err = render(
        &Scene::new(0.0),
        &camera,
        &Isometry3::identity(),
        &RenderOptions { supersample: 0, ..Default::default() },
    )
    .unwrap_err();
    assert!(matches!(err, RenderError::InvalidOptions(_)), "{err}");
    assert!(matches!(RayTable::new(&pinhole(0, 10, 10.0)), Err(RenderError::InvalidCamera(_))));
}

#[test]
fn ray_table_is_reusable_across_frames() {
    let camera = fisheye().scaled(200, 150);
    let table = RayTable::new(&camera).unwrap();
    let scene = textured_scene();
    let opts = RenderOptions::default();
    for p in [Isometry3::identity(), pose(2.0, 3.0, 1.0, [0.01, 0.0, 0.0])] {
        let a = render_with_rays(&scene, &table, &p, &opts).unwrap();
        let b = render(&scene, &camera, &p, &opts).unwrap();
        assert_eq!(a, b);
    }
}
