//! Real AprilTag photos: the AprilTag library's own test set (3 NASA Swarmathon photos, 799x533,
//! many small tag36h11 tags), shipped by the crates.io crate apriltag-sys 0.4.0 together with the
//! corners AprilTag 3 finds in each. scripts/fetch-apriltag-photos.sh (run by scripts/setup.sh)
//! fetches it with cargo into .deps/apriltag-photos/.
//! Every tag found must have its corners within 0.5 px of the reference; at least 21 of the 47
//! reference tags must be found (OpenCV 4.6's aruco misses the tiniest, see below).
use abvs_camcal::detect::{apriltags, load_gray};
use std::path::PathBuf;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.deps/apriltag-photos")
}

fn parse_ref(text: &str) -> Vec<(u32, [[f64; 2]; 4])> {
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let (id, rest) = l.split_once(',').unwrap();
            let nums: Vec<f64> = rest
                .split(|c: char| c == '(' || c == ')' || c == ',' || c.is_whitespace())
                .filter(|t| !t.is_empty())
                .map(|t| t.parse().unwrap())
                .collect();
            assert_eq!(nums.len(), 8, "{l}");
            (id.trim().parse().unwrap(), std::array::from_fn(|k| [nums[2 * k], nums[2 * k + 1]]))
        })
        .collect()
}

#[test]
fn all_reference_tags_found_within_half_a_pixel() {
    let dir = data_dir();
    assert!(
        dir.join("README.md").is_file(),
        "{} missing: run scripts/setup.sh (or scripts/fetch-apriltag-photos.sh)",
        dir.display()
    );
    let mut worst: f64 = 0.0;
    let mut total = 0;
    let mut errs = Vec::new();
    let mut missing_all = 0;
    for stem in ["33369213973_9d9bb4cc96_c", "34085369442_304b6bafd9_c", "34139872896_defdb2f8d9_c"] {
        let reference = parse_ref(&std::fs::read_to_string(dir.join(format!("{stem}.txt"))).unwrap());
        let g = load_gray(&dir.join(format!("{stem}.jpg"))).unwrap();
        let found = apriltags(&g).unwrap();
        let mut missing = 0;
        for (id, rc) in &reference {
            // the detection of the same tag: same id, nearest centre
            let centre = |c: &[[f64; 2]; 4]| {
                [c.iter().map(|p| p[0]).sum::<f64>() / 4.0, c.iter().map(|p| p[1]).sum::<f64>() / 4.0]
            };
            let rcen = centre(rc);
            let best = found
                .iter()
                .filter(|(fid, _)| fid == id)
                .map(|(_, c)| {
                    let fc = centre(c);
                    (((fc[0] - rcen[0]).powi(2) + (fc[1] - rcen[1]).powi(2)).sqrt(), c)
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            match best {
                Some((d, c)) if d < 3.0 => {
                    for k in 0..4 {
                        let e = ((c[k][0] - rc[k][0]).powi(2) + (c[k][1] - rc[k][1]).powi(2)).sqrt();
                        worst = worst.max(e);
                        errs.push(e);
                    }
                }
                _ => {
                    missing += 1;
                    eprintln!("  missing: id {id} at {rc:?}");
                }
            }
            total += 1;
        }
        eprintln!("{stem}: {} reference tags, {} detections, {missing} missing", reference.len(), found.len());
        missing_all += missing;
    }
    errs.sort_by(|a, b| a.total_cmp(b));
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
    eprintln!(
        "{total} tags, {} corners: RMS {rms:.3} px, median {:.3} px, max {worst:.3} px",
        errs.len(),
        errs[errs.len() / 2]
    );
    // OpenCV 4.6's aruco decoder misses 26 of these 47 tags: all are tiny (12-20 px wide, often
    // seen edge-on on the cubes' side faces) where AprilTag 3's decoder still reads the bits.
    // The 21 it finds must stay found (and within 0.5 px); see camcal/README.md.
    assert!(total - missing_all >= 21, "only {} of {total} reference tags found", total - missing_all);
    assert!(worst < 0.5, "worst corner {worst} px from the reference");
}
