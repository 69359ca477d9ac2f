//! Every kind of bad dataset input is refused with the file name, the line and what is
//! wrong; good files (any column order, extras, optional groups) read and round-trip.
use abvs_eye::dataset::{Dataset, Sample, REQUIRED_COLUMNS};
use abvs_eye::error::EyeError;
use std::path::Path;

const HEADER: &str = "seq,t_s,theta1_deg,theta2_deg,theta3_deg,alpha_deg,beta_deg,gamma_deg,x_mm,y_mm,z_mm";
const ROW1: &str = "1,0.5,10,-5,20,1.5,-2,3,0.1,-0.2,0.3";
const ROW2: &str = "2,1.0,11,-4,21,2,-1,4,0.2,-0.1,0.4";

fn read_str(text: &str) -> abvs_eye::Result<Dataset> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("data.csv");
    std::fs::write(&path, text).unwrap();
    Dataset::read(&path)
}

/// Reads `text` as data.csv, expects a File error at `line` whose text has every `needle`.
fn refused(text: &str, line: usize, needles: &[&str]) -> String {
    let err = read_str(text).expect_err("bad input must be refused");
    let msg = err.to_string();
    match &err {
        EyeError::File { path, line: l, .. } => {
            assert_eq!(path.file_name().unwrap(), "data.csv", "{msg}");
            assert_eq!(*l, Some(line), "{msg}");
        }
        other => panic!("expected EyeError::File, got {other:?}"),
    }
    let loc = format!("data.csv:{line}:");
    assert!(msg.contains(&loc), "{msg:?} lacks {loc:?}");
    for n in needles {
        assert!(msg.contains(n), "{msg:?} lacks {n:?}");
    }
    msg
}

/// A file with the two good rows and `row` as line 4.
fn with_row(row: &str) -> String {
    format!("{HEADER}\n{ROW1}\n{ROW2}\n{row}\n")
}

/// ROW-like line with seq 3 and `col` set to `value`.
fn row_with(col: &str, value: &str) -> String {
    let mut f: Vec<String> = "3,1.5,12,-3,22,2.5,0,5,0.3,0,0.5".split(',').map(String::from).collect();
    let k = REQUIRED_COLUMNS.iter().position(|c| *c == col).unwrap();
    f[k] = value.to_string();
    f.join(",")
}

#[test]
fn empty_file() {
    refused("", 1, &["empty file", "header"]);
}

#[test]
fn missing_header() {
    refused(&format!("{ROW1}\n{ROW2}\n"), 1, &["missing header"]);
}

#[test]
fn missing_required_column() {
    let header = HEADER.replace(",theta2_deg", "");
    let row = "1,0.5,10,20,1.5,-2,3,0.1,-0.2,0.3";
    refused(&format!("{header}\n{row}\n"), 1, &["missing required column theta2_deg"]);
}

#[test]
fn duplicate_column() {
    refused(&format!("{HEADER},x_mm\n"), 1, &["duplicate column", "x_mm"]);
    refused(&format!("{HEADER},note,note\n"), 1, &["duplicate column", "note"]);
}

#[test]
fn wrong_field_count() {
    refused(&with_row("3,1.5,12,-3,22,2.5,0,5,0.3,0"), 4, &["wrong number of fields", "10", "11"]);
    refused(&with_row("3,1.5,12,-3,22,2.5,0,5,0.3,0,0.5,9"), 4, &["wrong number of fields"]);
}

#[test]
fn non_number() {
    let m = refused(&with_row(&row_with("theta2_deg", "abc")), 4, &["column theta2_deg", "not a number"]);
    assert!(m.contains("\"abc\""), "{m}");
    refused(&with_row(&row_with("z_mm", "")), 4, &["column z_mm", "not a number"]);
    refused(&with_row(&row_with("seq", "x3")), 4, &["column seq", "not a number"]);
    refused(&with_row(&row_with("seq", "3.5")), 4, &["column seq", "not a non-negative integer"]);
}

#[test]
fn nan_or_infinite() {
    for v in ["NaN", "inf", "-infinity", "1e400"] {
        refused(&with_row(&row_with("alpha_deg", v)), 4, &["column alpha_deg", "not a finite number"]);
    }
    refused(&with_row(&row_with("t_s", "nan")), 4, &["column t_s", "not a finite number"]);
}

#[test]
fn seq_not_increasing() {
    refused(&with_row(&row_with("seq", "2")), 4, &["column seq", "previous seq 2", "line 3"]);
    refused(&with_row(&row_with("seq", "1")), 4, &["column seq", "not greater"]);
}

#[test]
fn negative_time() {
    refused(&with_row(&row_with("t_s", "-0.25")), 4, &["column t_s", "negative"]);
}

#[test]
fn angle_or_position_out_of_range() {
    let cases = [
        ("theta1_deg", "360.5"),
        ("theta3_deg", "-361"),
        ("alpha_deg", "90.001"),
        ("gamma_deg", "-95"),
        ("beta_deg", "180.5"),
        ("x_mm", "1000.1"),
        ("y_mm", "-2000"),
    ];
    for (col, v) in cases {
        refused(&with_row(&row_with(col, v)), 4, &[&format!("column {col}"), "outside the physical range"]);
    }
    // The limits themselves are fine.
    let ok = format!("{HEADER}\n3,0,-360,360,0,-90,180,90,-1000,1000,0\n");
    assert_eq!(read_str(&ok).unwrap().len(), 1);
}

#[test]
fn cmd_out_of_range() {
    let text = format!("{HEADER},cmd_alpha_deg,cmd_beta_deg,cmd_gamma_deg\n{ROW1},1,2,3\n{ROW2},1,200,3\n");
    refused(&text, 3, &["column cmd_beta_deg", "outside the physical range [-180, 180]"]);
}

#[test]
fn gravity_not_unit() {
    let text = format!("{HEADER},gx,gy,gz\n{ROW1},0,1,0\n{ROW2},0,1.01,0\n");
    refused(&text, 3, &["gx, gy, gz", "not a unit vector"]);
    // Within 1e-3 of unit is accepted as is.
    let text = format!("{HEADER},gx,gy,gz\n{ROW1},0,1.0009,0\n");
    assert_eq!(read_str(&text).unwrap().samples[0].gravity, Some([0.0, 1.0009, 0.0]));
}

#[test]
fn partial_optional_group() {
    let text = format!("{HEADER},cmd_alpha_deg,cmd_gamma_deg\n{ROW1},1,2\n");
    refused(&text, 1, &["incomplete column group", "cmd_beta_deg is missing"]);
    let text = format!("{HEADER},gx,gz\n{ROW1},0,0\n");
    refused(&text, 1, &["incomplete column group", "gy is missing"]);
}

#[test]
fn physical_lines_count_quoted_newlines_and_blank_lines() {
    // Line numbers are physical lines, even past blank lines and quoted newlines.
    let text = format!("{HEADER},note\n{ROW1},\"two\nlines\"\n\n{},x\n", row_with("theta1_deg", "abc"));
    refused(&text, 5, &["column theta1_deg"]);
    // CRLF line ends, blank lines before the header, no final line break.
    let text = format!("\r\n\r\n{HEADER}\r\n{ROW1}\r\n\r\n{}", row_with("x_mm", "1e9"));
    refused(&text, 6, &["column x_mm", "outside"]);
    let text = format!("\n{HEADER}\n{ROW1}\n{ROW1}\n");
    refused(&text, 4, &["column seq", "previous seq 1 (line 3)"]);
}

#[test]
fn invalid_utf8_names_the_line() {
    let mut bytes = format!("{HEADER},note\n{ROW1},ok\n{ROW2},").into_bytes();
    bytes.extend([0xff, 0xfe, b'\n']);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("data.csv");
    std::fs::write(&path, bytes).unwrap();
    let e = Dataset::read(&path).unwrap_err().to_string();
    assert!(e.contains("data.csv:3:") && e.contains("UTF-8"), "{e}");
}

#[test]
fn from_reader_names_the_source() {
    let err = Dataset::from_reader(format!("{HEADER}\n{}\n", row_with("y_mm", "?")).as_bytes(), Path::new("eye0.csv"))
        .unwrap_err();
    assert!(err.to_string().starts_with("eye0.csv:2: column y_mm"), "{err}");
}

#[test]
fn header_only_is_an_empty_dataset() {
    let ds = read_str(&format!("{HEADER}\n")).unwrap();
    assert!(ds.is_empty());
    assert_eq!(ds.len(), 0);
}

#[test]
fn columns_by_name_in_any_order_with_extras() {
    let text = "z_mm, note ,y_mm,x_mm,gamma_deg,beta_deg,alpha_deg,theta3_deg,theta2_deg,theta1_deg,t_s,seq\n\
                3, hello ,2,1,-4,5,6,7,8,9,0.25,17\n";
    let ds = read_str(text).unwrap();
    assert_eq!(ds.extra_columns, vec!["note".to_string()]);
    let s = &ds.samples[0];
    assert_eq!(s.seq, 17);
    assert_eq!(s.t_s, 0.25);
    assert_eq!(s.theta_deg, [9.0, 8.0, 7.0]);
    assert_eq!(s.pose, [6.0, 5.0, -4.0, 1.0, 2.0, 3.0]);
    assert_eq!(s.extra, vec!["hello".to_string()]);
    assert_eq!(s.cmd_deg, None);
    assert_eq!(s.gravity_or_default(), [0.0, 1.0, 0.0]);
}

fn bits(ds: &Dataset) -> Vec<u64> {
    let mut v = Vec::new();
    for s in &ds.samples {
        v.push(s.seq);
        v.push(s.t_s.to_bits());
        v.extend(s.theta_deg.iter().chain(&s.pose).map(|x| x.to_bits()));
        v.extend(s.cmd_deg.iter().flatten().map(|x| x.to_bits()));
        v.extend(s.gravity.iter().flatten().map(|x| x.to_bits()));
    }
    v
}

#[test]
fn round_trip_is_bit_exact() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let awkward = [0.1 + 0.2, 1.0 / 3.0, -0.0, 5e-324, f64::MIN_POSITIVE, 1e-17, 89.99999999999999];
    let mut samples = Vec::new();
    for k in 0..200u64 {
        let mut r = |lim: f64| -> f64 {
            if rng.gen_bool(0.1) {
                awkward[rng.gen_range(0..awkward.len())]
            } else {
                rng.gen_range(-lim..lim)
            }
        };
        let g = [r(1.0), r(1.0) + 2.0, r(1.0)];
        let n = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        samples.push(Sample {
            seq: 3 * k + 1,
            t_s: r(100.0).abs(),
            theta_deg: [r(360.0), r(360.0), r(360.0)],
            pose: [r(90.0), r(180.0), r(90.0), r(1000.0), r(1000.0), r(1000.0)],
            cmd_deg: Some([r(90.0), r(180.0), r(90.0)]),
            gravity: Some(g.map(|x| x / n)),
            extra: vec![format!("run {k}, \"quoted\""), String::new()],
        });
    }
    let ds = Dataset { samples, extra_columns: vec!["note".into(), "empty".into()] };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rt.csv");
    ds.write(&path).unwrap();
    let back = Dataset::read(&path).unwrap();
    assert_eq!(bits(&back), bits(&ds));
    assert_eq!(back.extra_columns, ds.extra_columns);
    assert_eq!(
        back.samples.iter().map(|s| &s.extra).collect::<Vec<_>>(),
        ds.samples.iter().map(|s| &s.extra).collect::<Vec<_>>()
    );
    assert_eq!(back.content_hash(), ds.content_hash());
    let header = std::fs::read_to_string(&path).unwrap().lines().next().unwrap().to_string();
    assert_eq!(header, format!("{HEADER},cmd_alpha_deg,cmd_beta_deg,cmd_gamma_deg,gx,gy,gz,note,empty"));
}

#[test]
fn content_hash_is_stable_and_sensitive() {
    let ds = read_str(&format!("{HEADER}\n{ROW1}\n{ROW2}\n")).unwrap();
    let h = ds.content_hash();
    assert_eq!(h.len(), 16);
    assert_eq!(h, ds.clone().content_hash());
    let mut other = ds.clone();
    other.samples[1].pose[4] = f64::from_bits(other.samples[1].pose[4].to_bits() + 1);
    assert_ne!(other.content_hash(), h);
    assert_ne!(Dataset::default().content_hash(), h);
}

#[test]
fn writer_refuses_what_it_could_not_read_back() {
    let mut ds = read_str(&format!("{HEADER}\n{ROW1}\n{ROW2}\n")).unwrap();
    ds.samples[1].cmd_deg = Some([0.0; 3]);
    let e = ds.to_writer(Vec::new()).unwrap_err().to_string();
    assert!(e.contains("cmd_*") && e.contains(":3:"), "{e}");
    ds.samples[1].cmd_deg = None;
    ds.samples[1].pose[0] = 120.0;
    let e = ds.to_writer(Vec::new()).unwrap_err().to_string();
    assert!(e.contains("column alpha_deg") && e.contains("outside"), "{e}");
}
