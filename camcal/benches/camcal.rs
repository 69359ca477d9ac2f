//! Detection time per 1600x1200 image (both AprilGrid detectors) and pose solve per image, on a
//! rendered four-board image through the OV8856 fisheye. Medians go to camcal/BENCHMARKS.md.
use abvs_camcal::detect::{aprilgrid_crate_tags, detect, gray_mat, AprilDetector, Detection};
use abvs_camcal::measure::{solve, SolveOptions};
use abvs_camcal::render_grid::GridScene;
use abvs_camcal::saddle::refine_tags;
use abvs_camcal::target::{AprilGridSpec, Target};
use abvs_camera::Camera;
use abvs_eye::Pose;
use abvs_render::RenderOptions;
use criterion::{criterion_group, criterion_main, Criterion};

fn bench(c: &mut Criterion) {
    let cam = Camera::ov8856();
    let grid = GridScene::paper(AprilGridSpec::default());
    let scene = grid.scene().unwrap();
    let target = Target::AprilGrid(grid.spec);
    let opts = RenderOptions { supersample: 3, blur_sigma: 0.6, noise_sigma: 1.0, ..Default::default() };
    let poses = [[0.0; 6], [10.0, -5.0, -15.0, 0.5, -1.0, 2.0]];
    let imgs: Vec<_> = poses
        .iter()
        .map(|p| {
            let r = grid.render(&scene, &cam, &Pose::from_p6(p), &opts).unwrap();
            gray_mat(r.width, r.height, &r.gray).unwrap()
        })
        .collect();
    let mut g = c.benchmark_group("detect_1600x1200");
    g.sample_size(10);
    g.bench_function("opencv_aruco_saddle", |b| b.iter(|| detect(&imgs[1], &target, AprilDetector::OpenCv).unwrap()));
    g.bench_function("aprilgrid_crate", |b| {
        b.iter(|| detect(&imgs[1], &target, AprilDetector::AprilGridCrate).unwrap())
    });
    // the two halves of the default detector: finding the tags, refining their corners
    let tags = aprilgrid_crate_tags(&imgs[1], &grid.spec).unwrap();
    g.bench_function("aprilgrid_crate_tags_only", |b| b.iter(|| aprilgrid_crate_tags(&imgs[1], &grid.spec).unwrap()));
    g.bench_function("saddle_refinement_only", |b| b.iter(|| refine_tags(&imgs[1], &tags).unwrap()));
    g.finish();

    // pose solve: home + one moved image (boards and one camera pose jointly), per image
    let dets: Vec<Result<Detection, _>> =
        imgs.iter().map(|m| Ok(detect(m, &target, AprilDetector::AprilGridCrate).unwrap())).collect();
    let home = [true, false];
    let mut g = c.benchmark_group("solve");
    g.sample_size(10);
    g.bench_function("home_plus_one_image", |b| {
        b.iter(|| solve(&cam, &target, &dets, &home, &SolveOptions::default()).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
