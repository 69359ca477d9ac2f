//! Render times: calibration-board frames at full OV8856 resolution and a 10-object stereo-style
//! scene at 640x480. Medians go to render/BENCHMARKS.md.

use std::sync::Arc;

use abvs_render::{render_with_rays, Camera, Filter, RayTable, RenderOptions, Scene, Surface, Texture};
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

fn pose(rx: f64, ry: f64, rz: f64, t: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(rx.to_radians(), ry.to_radians(), rz.to_radians()),
    )
}

/// Four 6x6 AprilGrid-sized boards (0.8 m, nearest-texel binary texture) around 1.5 m.
fn boards() -> Scene {
    let tex = Arc::new(
        Texture::from_texel_fn(240, 240, |i, j| (((i / 10) * 7 + (j / 10) * 3) % 5 < 2) as u8 as f32)
            .unwrap()
            .with_filter(Filter::Nearest),
    );
    let mut scene = Scene::new(0.5);
    for (k, (x, y)) in [(-0.7, -0.5), (0.6, -0.45), (-0.65, 0.5), (0.55, 0.55)].into_iter().enumerate() {
        let p = pose(10.0 * k as f64 - 15.0, 20.0 - 12.0 * k as f64, 5.0, [x, y, 1.5]);
        scene.surfaces.push(Surface::rect_centred(p, 0.8, 0.8, tex.clone()).unwrap());
    }
    scene
}

/// Ten objects at 0.2-2 m: backdrop, floor, slanted boards, boxes, spheres.
fn objects() -> Scene {
    let noise = Arc::new(
        Texture::from_texel_fn(256, 256, |i, j| (((i * 2654435761) ^ (j * 40503)) % 251) as f32 / 250.0).unwrap(),
    );
    let tiles = Arc::new(Texture::checkerboard(8, 8).unwrap().with_metric_size(0.4, 0.4).unwrap());
    let t = |x: &Arc<Texture>| x.clone();
    let s = vec![
        Surface::rect_centred(Isometry3::translation(0.0, 0.0, 2.0), 4.0, 3.0, t(&noise)).unwrap(),
        Surface::rect_centred(pose(90.0, 0.0, 0.0, [0.0, 0.5, 1.0]), 4.0, 3.0, t(&tiles)).unwrap(),
        Surface::rect_centred(pose(0.0, 40.0, 0.0, [-0.4, 0.0, 1.2]), 0.5, 0.6, t(&noise)).unwrap(),
        Surface::rect_centred(pose(20.0, -30.0, 0.0, [0.4, -0.1, 0.9]), 0.4, 0.4, t(&tiles)).unwrap(),
        Surface::cuboid(pose(0.0, 30.0, 0.0, [0.0, 0.3, 0.8]), Vector3::new(0.1, 0.1, 0.1), t(&noise)).unwrap(),
        Surface::cuboid(pose(10.0, -20.0, 5.0, [0.3, 0.25, 1.4]), Vector3::new(0.2, 0.15, 0.1), t(&tiles)).unwrap(),
        Surface::cuboid(pose(0.0, 0.0, 0.0, [-0.2, -0.3, 0.4]), Vector3::new(0.03, 0.03, 0.03), t(&noise)).unwrap(),
        Surface::sphere(Point3::new(-0.2, 0.1, 0.6), 0.08, t(&noise)).unwrap(),
        Surface::sphere(Point3::new(0.1, -0.2, 0.25), 0.03, t(&tiles)).unwrap(),
        Surface::sphere(Point3::new(0.5, 0.2, 1.6), 0.25, t(&noise)).unwrap(),
    ];
    Scene { surfaces: s, background: 0.3 }
}

fn bench(c: &mut Criterion) {
    let full = Camera::ov8856();
    let mut g = c.benchmark_group("render");
    g.sample_size(10);
    g.bench_function("ray_table_1600x1200_fisheye", |b| b.iter(|| RayTable::new(&full).unwrap()));
    let table = RayTable::new(&full).unwrap();
    let scene = boards();
    let id = Isometry3::identity();
    for n in [1, 2] {
        let opts = RenderOptions { supersample: n, ..Default::default() };
        g.bench_function(format!("1600x1200_fisheye_4_boards_ss{n}"), |b| {
            b.iter(|| render_with_rays(&scene, &table, &id, &opts).unwrap())
        });
    }
    let small = RayTable::new(&full.scaled(640, 480)).unwrap();
    let scene = objects();
    let opts = RenderOptions::default();
    g.bench_function("640x480_fisheye_10_objects_ss1", |b| {
        b.iter(|| render_with_rays(&scene, &small, &id, &opts).unwrap())
    });
    let opts =
        RenderOptions { supersample: 2, blur_sigma: 0.8, vignetting: 0.5, noise_sigma: 2.0, ..Default::default() };
    g.bench_function("640x480_fisheye_10_objects_ss2_blur_vignetting_noise", |b| {
        b.iter(|| render_with_rays(&scene, &small, &id, &opts).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
