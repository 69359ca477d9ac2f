//! Rectified 640x480 pairs of the session scene generator with their exact disparity: development data with
//! ground truth for census-refine's confidence (scripts/fit_census_confidence.py), beside Aloe.
//! `cargo run -p abvs-sim --example rendered_pairs -- OUTDIR FIRST_SEED COUNT` writes
//! `OUTDIR/s{seed}/{left,right}.png` and `gt.pfm` (f B / Z, inf where nothing was hit). Each seed draws the
//! scene (`synth::scene`), the gaze, the baseline and the noise; odd seeds add low-texture boxes and a
//! nearly flat panel (walls and furniture the noise textures of the generator lack).
use abvs_render::{RenderOptions, Surface, Texture};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let (out, first, n): (&str, u64, u64) = (&a[1], a[2].parse().unwrap(), a[3].parse().unwrap());
    let (w, h) = (640u32, 480u32);
    for seed in first..first + n {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xd15);
        let mut scene = abvs_sim::synth::scene(seed).unwrap();
        if seed % 2 == 1 {
            for _ in 0..3 {
                let c = Point3::new(rng.gen_range(-0.4..0.4), rng.gen_range(-0.2..0.25), rng.gen_range(0.5..1.3));
                let half = Vector3::new(rng.gen_range(0.05..0.2), rng.gen_range(0.05..0.2), rng.gen_range(0.05..0.2));
                let iso = Isometry3::from_parts(
                    Translation3::new(c.x, c.y, c.z),
                    UnitQuaternion::from_euler_angles(0.0, rng.gen_range(-0.8..0.8), 0.0),
                );
                let v: f32 = rng.gen_range(0.2..0.8);
                scene = scene.with(Surface::cuboid(iso, half, Texture::constant(v)).unwrap());
            }
            let (g0, g1): (f32, f32) = (rng.gen_range(0.3..0.7), rng.gen_range(0.01..0.05));
            let panel = Isometry3::from_parts(
                Translation3::new(rng.gen_range(-0.5..0.5), rng.gen_range(-0.3..0.0), rng.gen_range(1.0..1.4)),
                UnitQuaternion::from_euler_angles(0.0, rng.gen_range(-0.5..0.5), 0.0),
            );
            let tex = Texture::procedural(move |u, v| g0 + g1 * ((u * 3.0).sin() * (v * 2.0).cos()) as f32);
            scene = scene.with(Surface::rect_centred(panel, 0.8, 0.6, tex).unwrap());
        }
        let f = rng.gen_range(260.0..360.0);
        let b = rng.gen_range(0.05..0.08);
        let cam = abvs_camera::Camera::pinhole(w, h, f);
        let look = UnitQuaternion::from_euler_angles(rng.gen_range(-0.2..0.2), rng.gen_range(-0.3..0.3), 0.0);
        let noise = rng.gen_range(0.5..3.0);
        let opts =
            |s| RenderOptions { supersample: 2, noise_sigma: noise, seed: s, blur_sigma: 0.4, ..Default::default() };
        let left = Isometry3::from_parts(Translation3::identity(), look);
        let right = Isometry3::from_parts(Translation3::from(look * Vector3::new(b, 0.0, 0.0)), look);
        let l = abvs_render::render(&scene, &cam, &left, &opts(seed * 2)).unwrap();
        let r = abvs_render::render(&scene, &cam, &right, &opts(seed * 2 + 1)).unwrap();
        let dir = std::path::Path::new(out).join(format!("s{seed}"));
        std::fs::create_dir_all(&dir).unwrap();
        l.gray_image().save(dir.join("left.png")).unwrap();
        r.gray_image().save(dir.join("right.png")).unwrap();
        let gt: Vec<f32> =
            l.depth.iter().map(|z| if z.is_finite() { (f * b / *z as f64) as f32 } else { f32::INFINITY }).collect();
        abvs_disparity::pfm::write_pfm(&dir.join("gt.pfm"), w as usize, h as usize, &gt).unwrap();
        eprintln!("s{seed}: f {f:.0} px, baseline {b:.3} m, noise {noise:.1}");
    }
}
