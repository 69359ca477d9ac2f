//! The driver: simulates each unit's sessions, trains and fine-tunes every model, saves it,
//! loads it back and scores it, then writes the figures, `summary.json` and `report.md`.
use crate::conclusions::{conclusions, headline};
use crate::config::{paper_unit, PaperConfig, RESTRICTED_DEG};
use crate::error::{PaperError, Result};
use crate::figures::{plot_fig7, plot_fig8};
use crate::reference::{PAPER_M2_FULL, PAPER_M2_RESTRICTED, T3_ORDER};
use crate::report::report_md;
use crate::scored::{Scored, TestSet};
use crate::summary::*;
use abvs_calib::methods::{finetune, fit, validation_mask, FitConfig, Method};
use abvs_calib::metrics::evaluate;
use abvs_calib::model::{save_model, FkModel, ModelParts};
use abvs_calib::mpe::Target;
use abvs_eye::dataset::{Dataset, Sample};
use abvs_eye::sim::{simulate_dataset, Commanded, SimSpec};
use abvs_eye::{UnitModel, WORKSPACE_DEG};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A trained model, loaded back from its directory.
struct Trained {
    name: String,
    model: FkModel,
    trained_on: String,
    samples: usize,
    seconds: f64,
    epochs: Vec<usize>,
}

struct Ctx<'a> {
    cfg: &'a PaperConfig,
    models: PathBuf,
    t0: Instant,
    stage_t0: Instant,
    stages: Vec<(String, f64)>,
    progress: &'a mut dyn FnMut(&str),
    fit_cfg: FitConfig,
    target: Target,
    data: Vec<DataInfo>,
}

fn quiet(_: &str, _: usize, _: usize, _: f64, _: f64) {}

impl Ctx<'_> {
    fn log(&mut self, msg: &str) {
        let line = format!("[{:7.1} s] {msg}", self.t0.elapsed().as_secs_f64());
        (self.progress)(&line);
    }

    fn stage(&mut self, name: &str) {
        self.end_stage();
        self.stages.push((name.to_string(), f64::NAN));
        self.stage_t0 = Instant::now();
        self.log(&format!("== {name}"));
    }

    fn end_stage(&mut self) {
        if let Some(last) = self.stages.last_mut() {
            if last.1.is_nan() {
                last.1 = self.stage_t0.elapsed().as_secs_f64();
            }
        }
    }

    fn simulate(&mut self, unit_name: &str, unit: &UnitModel, session: &str, spec: SimSpec) -> Result<Dataset> {
        let (data, st) = simulate_dataset(unit, &spec, |_, _| {})?;
        self.data.push(DataInfo {
            unit: unit_name.into(),
            session: session.into(),
            commanded: st.commanded,
            written: st.written,
            max_dev_rot_deg: st.max_dev_rot_deg,
            max_dev_trans_mm: st.max_dev_trans_mm,
        });
        Ok(data)
    }

    /// Saves the model and loads it back: what is scored is what was written.
    fn keep(
        &mut self,
        name: &str,
        parts: ModelParts,
        trained_on: String,
        samples: usize,
        t: Instant,
    ) -> Result<Trained> {
        let dir = self.models.join(name);
        save_model(&dir, &parts)?;
        let model = FkModel::load(&dir)?;
        Ok(Trained {
            name: name.into(),
            model,
            trained_on,
            samples,
            seconds: t.elapsed().as_secs_f64(),
            epochs: parts.manifest.training.epochs.clone(),
        })
    }

    fn fit(&mut self, name: &str, method: Method, data: &Dataset, val: Option<&Dataset>, on: &str) -> Result<Trained> {
        let t = Instant::now();
        let parts = fit(method, data, val, &self.fit_cfg, &mut quiet)?;
        self.keep(name, parts, on.into(), data.len(), t)
    }

    fn finetune(&mut self, name: &str, method: Method, base: &FkModel, data: &Dataset, on: &str) -> Result<Trained> {
        let t = Instant::now();
        // No validation set beyond the fine-tuning samples (10 % held out): with n^3 samples
        // collected, that is all a user has.
        let parts = finetune(method, base, data, None, &self.fit_cfg, &mut quiet)?;
        self.keep(name, parts, on.into(), data.len(), t)
    }

    fn score(&mut self, label: &str, t: &Trained, test: &TestSet) -> Result<Scored> {
        let pred = t.model.predict_dataset(&test.data)?;
        let mut eval = evaluate(&pred, &test.meas, &self.target);
        let sq = pred
            .iter()
            .zip(&test.meas)
            .map(|(p, m)| (0..6).map(|k| (p[k] - m[k]).powi(2)).sum::<f64>() / 6.0)
            .collect();
        let mpe = std::mem::take(&mut eval.per_sample_mpe_px);
        eval.per_sample_rot_deg = Vec::new();
        let norm = |m: &std::collections::BTreeMap<&'static str, abvs_calib::metrics::AxisStats>| {
            m.values().map(|s| s.mean * s.mean).sum::<f64>().sqrt()
        };
        let result = ModelResult {
            label: label.into(),
            unit: test.unit.clone(),
            model: t.name.clone(),
            method: t.model.method(),
            trained_on: t.trained_on.clone(),
            train_samples: t.samples,
            train_seconds: t.seconds,
            epochs: t.epochs.clone(),
            rot_norm_of_means_deg: norm(&eval.rot_deg),
            trans_norm_of_means_mm: norm(&eval.trans_mm),
            eval,
        };
        self.log(&format!(
            "{} {label:<16} ({}, {:.1} s): rot {:.4} deg, trans {:.4} mm, MSE_total {:.5}, MPE {:.2} px",
            test.unit,
            t.trained_on,
            t.seconds,
            result.rot_norm_of_means_deg,
            result.trans_norm_of_means_mm,
            result.eval.mse_total,
            result.eval.mpe_px
        ));
        Ok(Scored { result, sq, mpe })
    }
}

/// Seed of one simulated session: the run's seed mixed with a fixed tag (FNV-1a).
fn sub_seed(seed: u64, tag: &str) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64 ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    for b in tag.bytes() {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn pick(d: &Dataset, keep: impl Fn(usize, &Sample) -> bool) -> Dataset {
    Dataset {
        samples: d.samples.iter().enumerate().filter(|(i, s)| keep(*i, s)).map(|(_, s)| s.clone()).collect(),
        extra_columns: d.extra_columns.clone(),
    }
}

fn cmd_of(s: &Sample) -> [f64; 3] {
    s.cmd_deg.unwrap_or([f64::NAN; 3])
}

/// Whether a commanded pose lies on the training grid (the simulator's grids start at -range).
fn on_grid(c: &[f64; 3], step: f64) -> bool {
    (0..3).all(|k| {
        let q = (c[k] + WORKSPACE_DEG[k]) / step;
        (q - q.round()).abs() < 1e-6
    })
}

fn inside_restricted(c: &[f64; 3]) -> bool {
    (0..3).all(|k| c[k].abs() <= RESTRICTED_DEG[k] + 1e-9)
}

/// The paper's split of a dense session: training-grid poses; the rest 1:10 validation : test.
fn split_dense(dense: &Dataset, cfg: &PaperConfig) -> (Dataset, Dataset, Dataset) {
    let train = pick(dense, |_, s| on_grid(&cmd_of(s), cfg.train_step_deg));
    let rest = pick(dense, |_, s| !on_grid(&cmd_of(s), cfg.train_step_deg));
    let is_val = validation_mask(rest.len(), 1.0 / 11.0, cfg.seed);
    let val = pick(&rest, |i, _| is_val[i]);
    let test = pick(&rest, |i, _| !is_val[i]);
    (train, val, test)
}

fn mean_where(v: &[f64], mask: impl Fn(usize) -> bool) -> f64 {
    let (s, n) = v
        .iter()
        .enumerate()
        .filter(|(i, x)| mask(*i) && x.is_finite())
        .fold((0.0, 0usize), |(s, n), (_, x)| (s + x, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

fn dense_spec(cfg: &PaperConfig, tag: &str) -> SimSpec {
    SimSpec { commanded: Commanded::Step(cfg.dense_step_deg), seed: sub_seed(cfg.seed, tag), ..Default::default() }
}

/// An n^3 fine-tuning grid. No dropout: whoever collects a few hundred poses re-takes the
/// failed ones, and the sizes stay the paper's 64..512.
fn grid_spec(cfg: &PaperConfig, n: usize, tag: &str) -> SimSpec {
    SimSpec { commanded: Commanded::PerAxis(n), seed: sub_seed(cfg.seed, tag), dropout: 0.0, ..Default::default() }
}

/// Runs every experiment and writes `report.md`, `summary.json` and the PNGs into `out`.
/// `progress` gets one line per stage and per trained model.
pub fn run_paper(cfg: &PaperConfig, out: &Path, progress: &mut dyn FnMut(&str)) -> Result<PaperSummary> {
    cfg.validate()?;
    std::fs::create_dir_all(out).map_err(|e| PaperError::io(out, e))?;
    let models = out.join("models");
    let fit_cfg =
        FitConfig { max_epochs: cfg.max_epochs, patience: cfg.patience, seed: cfg.seed, ..FitConfig::default() };
    let mut cx = Ctx {
        cfg,
        models: models.clone(),
        t0: Instant::now(),
        stage_t0: Instant::now(),
        stages: vec![],
        progress,
        fit_cfg,
        target: Target::paper(),
        data: vec![],
    };
    let r = run_all(&mut cx, out);
    if !cfg.keep_models {
        // The report directory keeps only report.md, summary.json and the figures.
        let _ = std::fs::remove_dir_all(&models);
    }
    r
}

fn run_all(cx: &mut Ctx, out: &Path) -> Result<PaperSummary> {
    let cfg = cx.cfg;
    let mut files = vec![];

    // ---- C0: data, Table II ----
    cx.stage("C0: simulate the dense session, split training / validation / test");
    let c0 = paper_unit("C0")?;
    let dense =
        cx.simulate("C0", &c0, &format!("dense {} deg grid", cfg.dense_step_deg), dense_spec(cfg, "C0/dense"))?;
    let (train, val, test) = split_dense(&dense, cfg);
    drop(dense);
    let c0_split = [train.len(), val.len(), test.len()];
    cx.log(&format!(
        "C0: {} training ({} deg grid), {} validation, {} test samples",
        train.len(),
        cfg.train_step_deg,
        val.len(),
        test.len()
    ));
    let test0 = TestSet::new("C0", test)?;
    let on = format!("C0 {} deg grid", cfg.train_step_deg);

    cx.stage("Table II: M_h, M1, M2, hybrid on C0");
    let mh = cx.fit("c0_mh", Method::Mh, &train, Some(&val), &on)?;
    let s_mh = cx.score("M_h", &mh, &test0)?;
    let m1 = cx.fit("c0_m1", Method::M1, &train, Some(&val), &on)?;
    let s_m1 = cx.score("M1", &m1, &test0)?;
    let m2 = cx.fit("c0_m2", Method::M2, &train, Some(&val), &on)?;
    let s_m2 = cx.score("M2", &m2, &test0)?;
    let hy = cx.fit("c0_hybrid", Method::Hybrid, &train, Some(&val), &on)?;
    let s_hy = cx.score("hybrid", &hy, &test0)?;

    // ---- hybrid from few samples ----
    cx.stage("C0: hybrid from scratch on n^3 grids");
    let mut hybrid_few = vec![];
    for &n in &cfg.hybrid_n {
        let d = cx.simulate("C0", &c0, &format!("{n}^3 grid"), grid_spec(cfg, n, &format!("C0/grid{n}")))?;
        let t = cx.fit(&format!("c0_hybrid_n{n}"), Method::Hybrid, &d, None, &format!("C0 {n}^3 grid"))?;
        hybrid_few.push(cx.score(&format!("hybrid ({} samples)", n * n * n), &t, &test0)?.result);
    }

    // ---- extrapolation ----
    cx.stage("Extrapolation: M2 and hybrid trained on the +-20 deg range");
    let spec = SimSpec {
        commanded: Commanded::Step(cfg.restricted_step_deg),
        range_deg: RESTRICTED_DEG,
        seed: sub_seed(cfg.seed, "C0/restricted"),
        ..Default::default()
    };
    let restricted =
        cx.simulate("C0", &c0, &format!("restricted +-20/12/20, {} deg grid", cfg.restricted_step_deg), spec)?;
    // A restricted collection has no poses outside its range to validate on either.
    let val_in = pick(&val, |_, s| inside_restricted(&cmd_of(s)));
    let on_r = format!("C0 +-20/12/20 deg, {} deg grid", cfg.restricted_step_deg);
    let m2r = cx.fit("c0_m2_restricted", Method::M2, &restricted, Some(&val_in), &on_r)?;
    let s_m2r = cx.score("M2'", &m2r, &test0)?;
    let hyr = cx.fit("c0_hybrid_restricted", Method::Hybrid, &restricted, Some(&val_in), &on_r)?;
    let s_hyr = cx.score("hybrid'", &hyr, &test0)?;
    let inside: Vec<bool> = test0.cmd.iter().map(inside_restricted).collect();
    let extrap_row = |label: &str, s: &Scored, paper: Option<[f64; 3]>| {
        let (i, o) = (mean_where(&s.sq, |k| inside[k]), mean_where(&s.sq, |k| !inside[k]));
        ExtrapRow {
            label: label.into(),
            trained_on: s.result.trained_on.clone(),
            train_samples: s.result.train_samples,
            mse_inside: i,
            mse_outside: o,
            mse_whole: s.result.eval.mse_total,
            outside_over_inside: o / i,
            paper,
        }
    };
    let extrapolation = vec![
        extrap_row("M2 (full range)", &s_m2, Some(PAPER_M2_FULL)),
        extrap_row("M2' (restricted)", &s_m2r, Some(PAPER_M2_RESTRICTED)),
        extrap_row("hybrid (full range)", &s_hy, None),
        extrap_row("hybrid' (restricted)", &s_hyr, None),
    ];
    drop((s_m2r, s_hyr, m2r, hyr));

    // ---- fine-tuning: Table III, Fig. 7 ----
    let mut table3: Vec<ModelResult> = vec![];
    let mut fig7: Vec<Fig7Point> = vec![];
    let mut fig8_c1: Vec<(String, Scored)> = vec![];
    let mut fig8_c1_test: Option<TestSet> = None;
    for uname in &cfg.finetune_units {
        cx.stage(&format!("{uname}: fine-tuning C0's models (Table III, Fig. 7)"));
        let unit = paper_unit(uname)?;
        let lower = uname.to_lowercase();
        let dense = cx.simulate(
            uname,
            &unit,
            &format!("dense {} deg grid", cfg.dense_step_deg),
            dense_spec(cfg, &format!("{uname}/dense")),
        )?;
        let (_, _, test) = split_dense(&dense, cfg);
        drop(dense);
        let test_u = TestSet::new(uname, test)?;
        // S depends only on the nominal kinematics: one pass serves every model's split.
        let s_test: Vec<f64> = {
            let mut st = m2.model.state();
            test_u
                .data
                .samples
                .iter()
                .map(|s| m2.model.psc(&mut st, &s.theta_deg))
                .collect::<abvs_calib::Result<_>>()?
        };
        let first = fig8_c1_test.is_none();
        let mut rows = vec![];
        let m1_as_is = cx.score("M1 of C0 as is", &m1, &test_u)?;
        rows.push(m1_as_is.result);
        let m2_as_is = cx.score("M2 of C0 as is", &m2, &test_u)?;
        rows.push(m2_as_is.result.clone());
        if first {
            fig8_c1.push(("M2 of C0 as is".into(), m2_as_is));
        }
        for &n in &cfg.finetune_n {
            let ns = n * n * n;
            let ft =
                cx.simulate(uname, &unit, &format!("{n}^3 grid"), grid_spec(cfg, n, &format!("{uname}/grid{n}")))?;
            let on = format!("{uname} {n}^3 grid");
            let mut scored = vec![];
            for (label, method, base) in [
                ("M4f", Method::M4f, &m2.model),
                ("M2f", Method::M2f, &m2.model),
                ("hybrid", Method::Hybrid, &hy.model),
            ] {
                let t = cx.finetune(&format!("{lower}_{}_n{n}", method.name()), method, base, &ft, &on)?;
                let s_init = t.model.manifest.psc.map(|p| p.s_init);
                scored.push((label, cx.score(label, &t, &test_u)?, s_init));
            }
            let s_init = scored[0].2.ok_or_else(|| PaperError::Data("m4f model without PSC split".into()))?;
            let internal: Vec<bool> = s_test.iter().map(|&s| s <= s_init).collect();
            let frac = internal.iter().filter(|&&b| b).count() as f64 / internal.len().max(1) as f64;
            for (label, s, _) in &scored {
                fig7.push(Fig7Point {
                    unit: uname.clone(),
                    label: label.to_string(),
                    n_per_axis: n,
                    samples: s.result.train_samples,
                    s_init,
                    internal_fraction: frac,
                    mse_total: s.result.eval.mse_total,
                    mse_internal: mean_where(&s.sq, |k| internal[k]),
                    mse_external: mean_where(&s.sq, |k| !internal[k]),
                });
            }
            if n == cfg.table_n {
                let t = cx.fit(&format!("{lower}_mh_n{n}"), Method::Mh, &ft, None, &on)?;
                rows.push(cx.score("M_h", &t, &test_u)?.result);
                let t = cx.finetune(&format!("{lower}_m1f_n{n}"), Method::M1f, &m1.model, &ft, &on)?;
                rows.push(cx.score("M1f", &t, &test_u)?.result);
                for (label, s, _) in scored {
                    rows.push(s.result.clone());
                    if first && label != "M2f" {
                        fig8_c1.push((format!("{label} ({ns})"), s));
                    }
                }
            }
        }
        rows.sort_by_key(|r| T3_ORDER.iter().position(|l| *l == r.label).unwrap_or(usize::MAX));
        table3.extend(rows);
        if first {
            fig8_c1_test = Some(test_u);
        }
    }

    // ---- figures ----
    cx.stage("Figures");
    let fig7_files = plot_fig7(out, &fig7, cfg)?;
    files.extend(fig7_files);
    let mut fig8 = vec![];
    let c0_maps: Vec<(String, &Scored)> =
        vec![("M_h".into(), &s_mh), ("M1".into(), &s_m1), ("M2".into(), &s_m2), ("hybrid".into(), &s_hy)];
    fig8.extend(plot_fig8(out, "fig8_c0", "C0", &test0, &c0_maps)?);
    if let Some(t) = &fig8_c1_test {
        let maps: Vec<(String, &Scored)> = fig8_c1.iter().map(|(l, s)| (l.clone(), s)).collect();
        fig8.extend(plot_fig8(out, &format!("fig8_{}", t.unit.to_lowercase()), &t.unit, t, &maps)?);
    }
    files.extend(fig8.iter().map(|m| m.file.clone()));

    // ---- summary, report ----
    cx.stage("Report");
    let table2 = vec![s_mh.result.clone(), s_m1.result.clone(), s_m2.result.clone(), s_hy.result.clone()];
    let mut summary = PaperSummary {
        config: cfg.clone(),
        seconds: 0.0,
        stages: vec![],
        data: std::mem::take(&mut cx.data),
        c0_split,
        noise_floor_mse: std::iter::once("C0")
            .chain(cfg.finetune_units.iter().map(|u| u.as_str()))
            .map(|u| {
                let n = paper_unit(u).map(|x| x.effects.measurement_noise).unwrap_or_default();
                (u.to_string(), (n.rot_deg.powi(2) + n.trans_mm.powi(2)) / 2.0)
            })
            .collect(),
        table2,
        hybrid_few,
        table3,
        fig7,
        extrapolation,
        fig8,
        headline: Default::default(),
        conclusions: vec![],
        files: vec![],
    };
    summary.headline = headline(&summary);
    summary.conclusions = conclusions(&summary);
    files.push("report.md".into());
    files.push("summary.json".into());
    summary.files = files;
    cx.end_stage();
    summary.stages = cx.stages.clone();
    summary.seconds = cx.t0.elapsed().as_secs_f64();
    let p = out.join("summary.json");
    let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
    std::fs::write(&p, json).map_err(|e| PaperError::io(&p, e))?;
    let p = out.join("report.md");
    std::fs::write(&p, report_md(&summary)).map_err(|e| PaperError::io(&p, e))?;
    cx.log(&format!("wrote {} ({:.0} s in all)", out.display(), summary.seconds));
    Ok(summary)
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_membership_and_split() {
        assert!(on_grid(&[-30.0, -15.0, 30.0], 3.0));
        assert!(on_grid(&[-27.0, 0.0, 3.0], 3.0));
        assert!(!on_grid(&[-29.0, 0.0, 3.0], 3.0));
        // The 6 deg grid's beta values are -15, -9, ... (the simulator's grids start at -range).
        assert!(on_grid(&[0.0, -9.0, 6.0], 6.0) && !on_grid(&[0.0, -12.0, 6.0], 6.0));
        assert!(inside_restricted(&[20.0, -12.0, 0.0]) && !inside_restricted(&[21.0, 0.0, 0.0]));
    }
}
