//! `abvs calib`: fit, fine-tune, evaluate and apply calibrated forward kinematics.
use crate::table::map_rows;
use abvs_calib::ik::outside_workspace;
use abvs_calib::methods::{self, FitConfig, Method};
use abvs_calib::metrics::evaluate_model;
use abvs_calib::model::{save_model, FkModel};
use abvs_eye::dataset::Dataset;
use abvs_eye::table::{GravityCols, Table};
use anyhow::bail;
use clap::{Args, Subcommand};
use indicatif::ProgressBar;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Subcommand)]
pub enum CalibCmd {
    /// Fit a model from scratch: mh, m1, m2 or hybrid.
    Fit(FitArgs),
    /// Fine-tune a model of another unit: m1f, m2f, m4f, mh or hybrid.
    Finetune(FinetuneArgs),
    /// Error statistics of a model on a dataset (the paper's table layout).
    Eval(EvalArgs),
    /// Predicted poses for the theta columns of a CSV.
    Predict(PredictArgs),
    /// Calibrated IK: link angles and encoder counts that reach target orientations (model's FK).
    Ik(IkArgs),
    /// Repeatability after ISO 9283 per target (the paper's Table I) from repeated approaches.
    Repeatability(crate::repeat::RepeatArgs),
    /// Regenerate the paper's experiments on simulated units (report.md + PNG).
    Paper(crate::paper::PaperArgs),
    /// Find where the model and the measurements disagree, name the missing effect, add it.
    Explain(crate::explain::ExplainArgs),
    /// Camera intrinsics from images of an AprilGrid or chessboard (OpenCV YAML).
    Intrinsics(crate::camcal::IntrinsicsArgs),
    /// Camera poses relative to home from an image session -> dataset file (bundle adjustment).
    Measure(crate::camcal::MeasureArgs),
    /// Stereo calibration at home: both intrinsics and T_lH^rH (OpenCV YAML).
    Stereo(crate::camcal::StereoArgs),
    /// Where a runtime self-check log (`abvs run --self-check-log`) puts the stereo error, and which eye's
    /// model it follows (report.md, summary.json, PNGs).
    SelfCheck(crate::self_check_report::SelfCheckArgs),
}

#[derive(Args)]
pub struct Common {
    /// Training data: a dataset CSV (docs/spec/dataset.md).
    #[arg(long)]
    train: PathBuf,
    /// Validation data (dataset CSV; default: a seeded 10% of --train held out); its metrics go into the manifest.
    #[arg(long)]
    val: Option<PathBuf>,
    /// Model directory to write (manifest.json, networks, unit.toml); an existing model is refused
    /// unless --force.
    #[arg(long)]
    out: PathBuf,
    /// Replace an existing model directory at --out whole (its old files removed).
    #[arg(long)]
    force: bool,
    /// Most training epochs (1 to 1000000; early stopping may end sooner).
    #[arg(long, default_value_t = 1000, value_parser = crate::args::count(1usize, 1_000_000))]
    max_epochs: usize,
    /// Seed of the validation split and of the networks' initial weights.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Hidden width of the networks (units per layer, 1 to 4096).
    #[arg(long, default_value_t = 64, value_parser = crate::args::count(1usize, 4096))]
    hidden: usize,
    /// Adam learning rate (in (0, 1]; the paper: 1e-4).
    #[arg(long, default_value_t = 1e-4, value_parser = crate::args::positive_up_to(1.0))]
    lr: f64,
}

#[derive(Args)]
pub struct FitArgs {
    /// Method to fit from scratch: mh (hand-eye), m1, m2 (the paper's networks) or hybrid (the unit's
    /// static effects plus a residual network).
    #[arg(long, value_parser = method_parser(&[Method::Mh, Method::M1, Method::M2, Method::Hybrid]))]
    method: Method,
    #[command(flatten)]
    c: Common,
}

#[derive(Args)]
pub struct FinetuneArgs {
    /// Method: m1f, m2f (fine-tune an m1 / m2 network), m4f (split an m2 network by the PSC), mh or hybrid
    /// (refit a physics model).
    #[arg(long, value_parser = method_parser(&[Method::M1f, Method::M2f, Method::M4f, Method::Mh, Method::Hybrid]))]
    method: Method,
    /// The model of another unit to start from (a model directory).
    #[arg(long)]
    base: PathBuf,
    #[command(flatten)]
    c: Common,
}

/// `--method` offering only the methods the subcommand accepts (clap lists exactly these in the help).
fn method_parser(ok: &'static [Method]) -> impl clap::builder::TypedValueParser<Value = Method> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(ok.iter().map(|m| m.name()))
        .map(|s| Method::parse(&s).expect("one of the listed methods"))
}

#[derive(Args)]
pub struct EvalArgs {
    /// Model directory (manifest.json + networks).
    #[arg(long)]
    model: PathBuf,
    /// Dataset CSV to score the model on (at least one sample).
    #[arg(long)]
    data: PathBuf,
    /// Print JSON instead of the table.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct PredictArgs {
    /// Model directory (manifest.json + networks).
    #[arg(long)]
    model: PathBuf,
    /// CSV with theta1_deg..theta3_deg (deg; optional gx, gy, gz; other columns kept), visited in order.
    #[arg(long = "in")]
    input: PathBuf,
    /// Output CSV: the input's columns plus the predicted pose (deg, mm).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
pub struct IkArgs {
    /// Model directory (manifest.json + networks).
    #[arg(long)]
    model: PathBuf,
    /// CSV with alpha_deg, beta_deg, gamma_deg (optional gx, gy, gz; other columns kept), visited in order.
    #[arg(long = "in")]
    input: PathBuf,
    /// Output CSV: the input's columns plus link angles (deg), predicted pose, residual (deg), counts.
    #[arg(long)]
    out: PathBuf,
    /// Also solve targets outside the calibrated workspace (the training data's range of each Fick
    /// angle, recorded in the manifest), where the model extrapolates; refused per row by default.
    #[arg(long)]
    allow_outside: bool,
}

/// One progress bar per stage of training.
struct Bars {
    stage: String,
    bar: Option<ProgressBar>,
}

impl Bars {
    fn update(&mut self, what: &str, step: usize, total: usize, a: f64, b: f64) {
        if self.stage != what {
            if let Some(b) = self.bar.take() {
                b.finish();
            }
            self.stage = what.to_string();
            self.bar = Some(crate::progress_bar(total as u64, what));
        }
        if let Some(bar) = &self.bar {
            bar.set_length(total as u64);
            bar.set_position(step as u64);
            if a.is_finite() {
                bar.set_message(format!("{what} {a:.4} / {b:.4}"));
            }
        }
    }
    fn done(&mut self) {
        if let Some(b) = self.bar.take() {
            b.finish();
        }
    }
}

fn cfg(c: &Common) -> FitConfig {
    FitConfig { max_epochs: c.max_epochs, seed: c.seed, hidden: c.hidden, lr: c.lr, ..FitConfig::default() }
}

/// `--out` before any training: an existing model is refused unless `--force`, and the directory
/// must be creatable (a fit of minutes must not end in a path error).
fn check_out(c: &Common) -> anyhow::Result<()> {
    abvs_runtime::outputs::check_dir_creatable("--out", &c.out)?;
    if c.out.join(abvs_fk::model::MANIFEST).exists() && !c.force {
        bail!("--out {}: a model is already there; give --force to replace it whole", c.out.display());
    }
    Ok(())
}

/// `--val`: an empty validation set would be stored as a perfect score.
fn read_val(c: &Common) -> anyhow::Result<Option<Dataset>> {
    let Some(p) = &c.val else { return Ok(None) };
    let d = Dataset::read(p)?;
    if d.is_empty() {
        bail!("--val {}: no samples (a header without rows); give validation data or leave --val out", p.display());
    }
    Ok(Some(d))
}

fn report(parts: &abvs_calib::model::ModelParts, c: &Common) -> anyhow::Result<ExitCode> {
    if c.force {
        // replaced whole: no network of the old model left beside the new manifest
        abvs_fk::model::remove_model(&c.out)?;
    }
    save_model(&c.out, parts)?;
    let m = &parts.manifest;
    eprintln!(
        "wrote {} ({}; {} training samples, {} validation; {:.1} s)",
        c.out.display(),
        m.method,
        m.training.samples,
        m.training.val_samples,
        m.training.seconds
    );
    for h in &m.held_parameters {
        eprintln!("held (not identifiable from these data): {h}");
    }
    Ok(ExitCode::SUCCESS)
}

impl CalibCmd {
    /// Output paths before any work.
    pub fn check(&self) -> anyhow::Result<()> {
        match self {
            CalibCmd::Fit(a) => check_out(&a.c),
            CalibCmd::Finetune(a) => check_out(&a.c),
            CalibCmd::SelfCheck(a) => a.check(),
            _ => Ok(()),
        }
    }
}

pub fn run(cmd: CalibCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        CalibCmd::Paper(a) => crate::paper::run(a),
        CalibCmd::Fit(FitArgs { method, c }) => {
            let train = Dataset::read(&c.train)?;
            let val = read_val(&c)?;
            let mut bars = Bars { stage: String::new(), bar: None };
            let parts =
                methods::fit(method, &train, val.as_ref(), &cfg(&c), &mut |w, s, t, a, b| bars.update(w, s, t, a, b))?;
            bars.done();
            report(&parts, &c)
        }
        CalibCmd::Finetune(FinetuneArgs { method, base, c }) => {
            let base = FkModel::load(&base)?;
            let train = Dataset::read(&c.train)?;
            let val = read_val(&c)?;
            let mut bars = Bars { stage: String::new(), bar: None };
            let parts = methods::finetune(method, &base, &train, val.as_ref(), &cfg(&c), &mut |w, s, t, a, b| {
                bars.update(w, s, t, a, b)
            })?;
            bars.done();
            report(&parts, &c)
        }
        CalibCmd::Eval(a) => {
            let data = Dataset::read(&a.data)?;
            if data.is_empty() {
                // nothing scored is not a perfect score
                bail!("--data {}: no samples to evaluate (a header without rows)", a.data.display());
            }
            let model = FkModel::load(&a.model)?;
            let r = evaluate_model(&model, &data)?;
            if a.json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                println!("model {} ({}) on {}", a.model.display(), model.method(), a.data.display());
                print!("{}", r.table());
            }
            Ok(ExitCode::SUCCESS)
        }
        CalibCmd::Explain(a) => crate::explain::run(a),
        CalibCmd::Intrinsics(a) => crate::camcal::intrinsics(a),
        CalibCmd::Measure(a) => crate::camcal::measure(a),
        CalibCmd::Stereo(a) => crate::camcal::stereo(a),
        CalibCmd::SelfCheck(a) => crate::self_check_report::run(a),
        CalibCmd::Ik(a) => ik(a),
        CalibCmd::Repeatability(a) => crate::repeat::stats(a),
        CalibCmd::Predict(a) => {
            let model = FkModel::load(&a.model)?;
            let mut st = model.state();
            let t = Table::read(&a.input)?;
            let g = GravityCols::find(&t);
            map_rows(
                t,
                &a.input,
                &a.out,
                &["theta1_deg", "theta2_deg", "theta3_deg"],
                &["alpha_deg", "beta_deg", "gamma_deg", "x_mm", "y_mm", "z_mm"],
                |v, line, row| {
                    let gr = g.of(&a.input, line, row)?;
                    model.eval(&mut st, &[v[0], v[1], v[2]], gr).map(|p| p.to_vec()).map_err(|e| e.to_string())
                },
            )
        }
    }
}

/// `abvs calib ik`: rows in order (each move starts where the previous one ended, so the
/// model's motion history is that of the sequence); a refused row keeps the links where they
/// were, is reported by its line and left with empty outputs.
fn ik(a: IkArgs) -> anyhow::Result<ExitCode> {
    let model = FkModel::load(&a.model)?;
    let solver = abvs_calib::ik::CalibratedIk::new(&model);
    let range = model.manifest.training.range_deg;
    let mut st = model.state();
    let t = Table::read(&a.input)?;
    let g = GravityCols::find(&t);
    let (mut worst, mut evals, mut solved) = (0.0f64, 0usize, 0usize);
    let code = map_rows(
        t,
        &a.input,
        &a.out,
        &["alpha_deg", "beta_deg", "gamma_deg"],
        &[
            "theta1_deg",
            "theta2_deg",
            "theta3_deg",
            "pred_alpha_deg",
            "pred_beta_deg",
            "pred_gamma_deg",
            "pred_x_mm",
            "pred_y_mm",
            "pred_z_mm",
            "residual_deg",
            "count1",
            "count2",
            "count3",
        ],
        |v, line, row| {
            let gr = g.of(&a.input, line, row)?;
            if let (Some(r), false) = (&range, a.allow_outside) {
                if let Some(o) = outside_workspace(r, [v[0], v[1], v[2]]) {
                    return Err(format!(
                        "{} {} deg is outside the calibrated workspace [{:.2}, {:.2}] deg (the training data's range; \
                         --allow-outside solves it anyway)",
                        o.axis, o.value_deg, o.range_deg[0], o.range_deg[1]
                    ));
                }
            }
            let s = solver.solve_and_move(&mut st, [v[0], v[1], v[2]], gr).map_err(|e| e.to_string())?;
            worst = worst.max(s.residual_deg);
            evals += s.evaluations;
            solved += 1;
            let mut out: Vec<f64> = s.theta_deg.to_vec();
            out.extend(s.pose);
            out.push(s.residual_deg);
            out.extend(s.counts().map(|c| c as f64));
            Ok(out)
        },
    )?;
    if solved > 0 {
        eprintln!(
            "calibrated IK ({}): {solved} targets, largest residual {worst:.1e} deg, {:.1} model evaluations per target",
            model.method(),
            evals as f64 / solved as f64
        );
    }
    Ok(code)
}
