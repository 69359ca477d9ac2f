//! Model files and the one evaluator of every calibrated FK.
//!
//! A model is a directory: `manifest.json` (method, version, normalisation, PSC thresholds,
//! physical parameters, training-data hash) plus its networks as ONNX files and, for the
//! physics-based methods, the unit model as TOML. [`FkModel`] loads any of them and evaluates
//! theta -> P. Networks follow the ONNX contract of [`crate::onnx_io`] (raw theta in degrees
//! in, raw P out), so a network trained elsewhere drops in: plain MLP graphs run natively
//! (fast), anything else through ONNX Runtime.
use crate::error::{FkError as CalibError, Result};
use crate::method::Method;
use crate::net::Net;
use crate::onnx_io::{export_onnx, import_onnx};
use abvs_eye::dataset::Dataset;
use abvs_eye::psc::{psc_at, psc_first_order, psc_map};
use abvs_eye::unit::{Conditions, UnitFk, UnitStream};
use abvs_eye::{SpmGeometry, UnitModel};
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

pub const MODEL_FORMAT: &str = "abvs-fk-model/1";
pub const MANIFEST: &str = "manifest.json";

/// The PSC split of an M4 model.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct PscSplit {
    /// Internal region: S <= s_init (rad/deg).
    pub s_init: f64,
    /// Training overlap: internal copy on S <= s_init + ds, external on S > s_init - ds.
    pub ds: f64,
    /// Fraction of the training samples with S <= s_init.
    pub internal_fraction: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, Default)]
pub struct TrainingInfo {
    /// `Dataset::content_hash` of the training data.
    pub data_hash: String,
    pub samples: usize,
    pub val_samples: usize,
    pub seed: u64,
    #[serde(default)]
    pub epochs: Vec<usize>,
    #[serde(default)]
    pub seconds: f64,
    /// Manifest method and data hash of the model this one was fine-tuned from.
    #[serde(default)]
    pub base: Option<String>,
    /// Smallest and largest alpha, beta, gamma (deg) of the training poses: the calibrated
    /// workspace (calibrated IK flags targets outside it). Absent in older manifests.
    #[serde(default)]
    pub range_deg: Option<[[f64; 2]; 3]>,
}

impl TrainingInfo {
    /// Each axis' [min, max] of the samples' Fick angles (None without samples).
    pub fn range_of(data: &Dataset) -> Option<[[f64; 2]; 3]> {
        if data.is_empty() {
            return None;
        }
        let mut r = [[f64::INFINITY, f64::NEG_INFINITY]; 3];
        for s in &data.samples {
            for k in 0..3 {
                r[k] = [r[k][0].min(s.pose[k]), r[k][1].max(s.pose[k])];
            }
        }
        Some(r)
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub method: Method,
    pub abvs_version: String,
    /// Input columns (deg) and output columns (deg, mm) of the model.
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    /// Role -> ONNX file in the directory: "net"; "internal"/"external" (m4f); "residual" (hybrid).
    #[serde(default)]
    pub networks: BTreeMap<String, String>,
    /// Per-network input/output normalisation (also inside the ONNX graphs; kept for reference).
    #[serde(default)]
    pub normalization: BTreeMap<String, serde_json::Value>,
    #[serde(default)]
    pub psc: Option<PscSplit>,
    /// Unit model file (mh, hybrid): the physical parameters.
    #[serde(default)]
    pub physics: Option<String>,
    /// Physical parameters the data could not separate (held at their starting values).
    #[serde(default)]
    pub held_parameters: Vec<String>,
    pub training: TrainingInfo,
    /// Metrics on the validation data at the end of training.
    #[serde(default)]
    pub validation: Option<serde_json::Value>,
    /// File -> hex SHA-256 of every network and unit file, written by `save_model` and checked by
    /// `FkModel::load` (absent in older manifests: nothing to check).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub sha256: BTreeMap<String, String>,
}

impl Manifest {
    pub fn new(method: Method) -> Self {
        Manifest {
            format: MODEL_FORMAT.into(),
            method,
            abvs_version: env!("CARGO_PKG_VERSION").into(),
            inputs: ["theta1_deg", "theta2_deg", "theta3_deg"].map(String::from).to_vec(),
            outputs: ["alpha_deg", "beta_deg", "gamma_deg", "x_mm", "y_mm", "z_mm"].map(String::from).to_vec(),
            networks: BTreeMap::new(),
            normalization: BTreeMap::new(),
            psc: None,
            physics: None,
            held_parameters: vec![],
            training: TrainingInfo::default(),
            validation: None,
            sha256: BTreeMap::new(),
        }
    }
}

/// What a method produced, ready to be written as a model directory.
pub struct ModelParts {
    pub manifest: Manifest,
    pub nets: Vec<(String, Net)>,
    pub unit: Option<UnitModel>,
}

/// Writes a model directory (created if needed).
pub fn save_model(dir: &Path, parts: &ModelParts) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| CalibError::io(dir, e))?;
    let mut m = parts.manifest.clone();
    for (role, net) in &parts.nets {
        let file = format!("{role}.onnx");
        export_onnx(net, &dir.join(&file))?;
        m.sha256.insert(file.clone(), crate::hash::sha256_file(&dir.join(&file))?);
        m.networks.insert(role.clone(), file);
        m.normalization.insert(role.clone(), serde_json::json!({"input": net.input_norm, "output": net.output_norm}));
    }
    if let Some(u) = &parts.unit {
        u.save(&dir.join("unit.toml"))?;
        m.sha256.insert("unit.toml".into(), crate::hash::sha256_file(&dir.join("unit.toml"))?);
        m.physics = Some("unit.toml".into());
    }
    let text = serde_json::to_string_pretty(&m).expect("manifest serialises");
    let p = dir.join(MANIFEST);
    std::fs::write(&p, text).map_err(|e| CalibError::io(&p, e))
}

/// Removes a model directory's manifest and the files it names (and the files any method
/// writes), so that a new model written there is whole; other files are left alone.
pub fn remove_model(dir: &Path) -> Result<()> {
    let mp = dir.join(MANIFEST);
    let mut files: Vec<String> =
        ["net.onnx", "internal.onnx", "external.onnx", "residual.onnx", "unit.toml"].map(String::from).to_vec();
    if let Ok(Ok(m)) = std::fs::read_to_string(&mp).map(|t| serde_json::from_str::<Manifest>(&t)) {
        files.extend(m.networks.into_values().chain(m.physics));
    }
    for f in files.iter().map(|f| dir.join(f)).chain([mp]) {
        // only files inside the directory, never a path a manifest smuggles out of it
        if f.parent() == Some(dir) && f.is_file() {
            std::fs::remove_file(&f).map_err(|e| CalibError::io(&f, e))?;
        }
    }
    Ok(())
}

/// Twice the largest |first-order S - exact S| over the workspace's 3 deg grid (computed once).
fn psc_margin() -> f64 {
    static MARGIN: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *MARGIN.get_or_init(|| {
        let g = SpmGeometry::nominal();
        let worst = psc_map(&g, 3.0)
            .iter()
            .filter_map(|p| {
                let th = p.theta_deg.map(f64::to_radians);
                let r = g.fk_cold(&th).ok()?.r;
                Some((psc_first_order(&g, &th, &r).ok()? - p.s).abs())
            })
            .fold(0.0, f64::max);
        2.0 * worst + 1e-6
    })
}

/// A network as it runs: natively when the file is a plain MLP graph, else through ort.
pub enum NetRunner {
    Native(Net),
    Ort { session: Mutex<ort::session::Session>, path: PathBuf },
}

impl NetRunner {
    pub fn load(path: &Path) -> Result<Self> {
        if !path.is_file() {
            return Err(CalibError::model(path, "network file missing"));
        }
        match import_onnx(path) {
            Ok(net) => Ok(NetRunner::Native(net)),
            Err(CalibError::NotMlp { .. }) => {
                let session = abvs_onnx::session(path, 1)?;
                check_ort_io(&session, path)?;
                Ok(NetRunner::Ort { session: Mutex::new(session), path: path.into() })
            }
            Err(e) => Err(e),
        }
    }

    pub fn eval(&self, x: &[f64; 3]) -> Result<[f64; 6]> {
        match self {
            NetRunner::Native(n) => Ok(n.eval(x)),
            NetRunner::Ort { session, path } => {
                let err = |e: ort::Error| CalibError::model(path, e.to_string());
                let input = ndarray::Array2::<f32>::from_shape_vec((1, 3), x.iter().map(|v| *v as f32).collect())
                    .expect("shape");
                let mut s = session.lock().expect("session lock");
                let tensor = ort::value::Tensor::from_array(input).map_err(err)?;
                let out = s.run(ort::inputs![crate::onnx_io::INPUT_NAME => tensor]).map_err(err)?;
                let (_, data) = out[0].try_extract_tensor::<f32>().map_err(err)?;
                if data.len() != 6 {
                    return Err(CalibError::model(path, format!("output has {} values, expected 6", data.len())));
                }
                Ok(std::array::from_fn(|k| data[k] as f64))
            }
        }
    }
}

fn check_ort_io(s: &ort::session::Session, path: &Path) -> Result<()> {
    let ins: Vec<String> = s.inputs().iter().map(|i| i.name().to_string()).collect();
    if ins.len() != 1 || ins[0] != crate::onnx_io::INPUT_NAME {
        return Err(CalibError::model(
            path,
            format!("expected one input named '{}' [N,3], found {ins:?}", crate::onnx_io::INPUT_NAME),
        ));
    }
    Ok(())
}

// One model per eye and process: the size difference between variants does not matter.
#[allow(clippy::large_enum_variant)]
enum Kind {
    Physics {
        fk: UnitFk,
        residual: Option<NetRunner>,
    },
    Net(NetRunner),
    /// `margin`: bound on |first-order S - exact S| over the workspace; only samples that close
    /// to the threshold pay for the exact (finite-step) S.
    Split {
        internal: NetRunner,
        external: NetRunner,
        split: PscSplit,
        margin: f64,
    },
}

/// Per-stream state of an evaluation: the motion history (backlash) and warm starts.
#[derive(Debug, Clone)]
pub struct FkState {
    /// The unit's stream (physics-based models).
    unit: Option<UnitStream>,
    nominal_warm: Matrix3<f64>,
}

/// Motion conditions frozen for a solver's candidate readings: see [`FkModel::freeze`].
#[derive(Debug, Clone)]
pub struct Frozen {
    /// Physics-based models: link approach directions, platform motion direction, gravity.
    cond: Option<Conditions>,
    /// Warm start: the unit's platform orientation (physics) or the nominal orientation (m4f).
    warm: Matrix3<f64>,
}

impl Frozen {
    /// Direction each link approaches from (+1 / -1; physics-based models only).
    pub fn link_dirs(&self) -> Option<[f64; 3]> {
        self.cond.map(|c| c.dir)
    }

    /// The last orientation solved (a start for the next solve nearby).
    pub fn warm(&self) -> Matrix3<f64> {
        self.warm
    }
}

/// Any calibrated forward kinematics, loaded from a model directory.
pub struct FkModel {
    pub manifest: Manifest,
    pub dir: PathBuf,
    kind: Kind,
    nominal: SpmGeometry,
}

impl FkModel {
    pub fn load(dir: &Path) -> Result<Self> {
        let mp = dir.join(MANIFEST);
        let text = std::fs::read_to_string(&mp).map_err(|e| CalibError::io(&mp, e))?;
        let manifest: Manifest =
            serde_json::from_str(&text).map_err(|e| CalibError::model(&mp, format!("bad manifest: {e}")))?;
        if manifest.format != MODEL_FORMAT {
            return Err(CalibError::model(&mp, format!("format '{}', expected '{MODEL_FORMAT}'", manifest.format)));
        }
        for (file, hash) in &manifest.sha256 {
            // a missing file is reported by its loader below, with what it is for
            if dir.join(file).is_file() {
                crate::hash::verify_sha256(&dir.join(file), &mp, hash)?;
            }
        }
        let net = |role: &str| -> Result<NetRunner> {
            let f = manifest
                .networks
                .get(role)
                .ok_or_else(|| CalibError::model(&mp, format!("method {} needs network '{role}'", manifest.method)))?;
            NetRunner::load(&dir.join(f))
        };
        let kind = match manifest.method {
            Method::Mh | Method::Hybrid => {
                let f =
                    manifest.physics.as_ref().ok_or_else(|| CalibError::model(&mp, "no physics (unit model) file"))?;
                let unit = UnitModel::load(&dir.join(f))?;
                let residual = if manifest.networks.contains_key("residual") { Some(net("residual")?) } else { None };
                Kind::Physics { fk: unit.compile()?, residual }
            }
            Method::M4f => Kind::Split {
                internal: net("internal")?,
                external: net("external")?,
                split: manifest.psc.ok_or_else(|| CalibError::model(&mp, "m4f model without PSC thresholds"))?,
                margin: psc_margin(),
            },
            Method::M1 | Method::M2 | Method::M1f | Method::M2f => Kind::Net(net("net")?),
        };
        Ok(FkModel { manifest, dir: dir.into(), kind, nominal: SpmGeometry::nominal() })
    }

    /// A physics-only (mh) model of a unit model held in memory: the nominal mechanism, or a unit-model
    /// file the runtime's FK reads, so that the IK and gaze of [`crate::ik`] run on any FK the runtime does.
    pub fn from_unit(unit: &UnitModel) -> Result<Self> {
        Ok(FkModel {
            manifest: Manifest::new(Method::Mh),
            dir: PathBuf::new(),
            kind: Kind::Physics { fk: unit.compile()?, residual: None },
            nominal: SpmGeometry::nominal(),
        })
    }

    pub fn method(&self) -> Method {
        self.manifest.method
    }

    /// The network of a role when it runs natively (for fine-tuning).
    pub fn native_net(&self, role: &str) -> Option<&Net> {
        match (&self.kind, role) {
            (Kind::Net(NetRunner::Native(n)), "net") => Some(n),
            (Kind::Split { internal: NetRunner::Native(n), .. }, "internal") => Some(n),
            (Kind::Split { external: NetRunner::Native(n), .. }, "external") => Some(n),
            (Kind::Physics { residual: Some(NetRunner::Native(n)), .. }, "residual") => Some(n),
            _ => None,
        }
    }

    /// The unit model behind a physics-based model.
    pub fn unit(&self) -> Option<&UnitModel> {
        match &self.kind {
            Kind::Physics { fk, .. } => Some(&fk.model),
            _ => None,
        }
    }

    pub fn state(&self) -> FkState {
        let unit = match &self.kind {
            Kind::Physics { fk, .. } => Some(fk.stream()),
            _ => None,
        };
        FkState { unit, nominal_warm: Matrix3::identity() }
    }

    /// The pose sensitivity coefficient of link angles (deg) on the nominal kinematics.
    pub fn psc(&self, st: &mut FkState, theta_deg: &[f64; 3]) -> Result<f64> {
        let th = theta_deg.map(f64::to_radians);
        let sol = self.nominal.fk_from(&th, &st.nominal_warm).or_else(|_| self.nominal.fk_cold(&th))?;
        st.nominal_warm = sol.r;
        Ok(psc_at(&self.nominal, &th, &sol.r)?)
    }

    /// theta (deg, encoder readings in acquisition order) -> P. `gravity` is B's gravity.
    pub fn eval(&self, st: &mut FkState, theta_deg: &[f64; 3], gravity: [f64; 3]) -> Result<[f64; 6]> {
        match &self.kind {
            Kind::Physics { fk, residual } => {
                let stream = st.unit.get_or_insert_with(|| fk.stream());
                let mut out = fk.next(stream, theta_deg, gravity)?.to_p6();
                if let Some(n) = residual {
                    let d = n.eval(theta_deg)?;
                    for k in 0..6 {
                        out[k] += d[k];
                    }
                }
                Ok(out)
            }
            Kind::Net(n) => n.eval(theta_deg),
            Kind::Split { internal, external, split, margin } => {
                let th = theta_deg.map(f64::to_radians);
                let sol = self.nominal.fk_from(&th, &st.nominal_warm).or_else(|_| self.nominal.fk_cold(&th))?;
                st.nominal_warm = sol.r;
                let mut s = psc_first_order(&self.nominal, &th, &sol.r)?;
                if (s - split.s_init).abs() <= *margin {
                    s = psc_at(&self.nominal, &th, &sol.r)?;
                }
                if s <= split.s_init {
                    internal.eval(theta_deg)
                } else {
                    external.eval(theta_deg)
                }
            }
        }
    }

    /// Freezes the conditions of a move from the stream state `st` to the readings `theta_deg`
    /// (deg): the direction each link approaches from and the direction of the platform's motion
    /// (backlash), and gravity. [`FkModel::eval_frozen`] then evaluates candidate readings near
    /// `theta_deg` as if each were that move's end, without advancing `st`: a smooth function
    /// for solvers. Models without motion history ignore the conditions.
    /// `near`: an orientation near the answer's (e.g. the nominal FK's), only to start the
    /// mechanism's Newton from; the result does not depend on it.
    pub fn freeze(
        &self,
        st: &FkState,
        theta_deg: &[f64; 3],
        gravity: [f64; 3],
        near: Option<&Matrix3<f64>>,
    ) -> Result<Frozen> {
        match &self.kind {
            Kind::Physics { fk, .. } => {
                let (cond, warm) = match &st.unit {
                    Some(s) => fk.peek(s, theta_deg, gravity, near)?,
                    None => fk.peek(&fk.stream(), theta_deg, gravity, near)?,
                };
                Ok(Frozen { cond: Some(cond), warm })
            }
            _ => Ok(Frozen { cond: None, warm: near.copied().unwrap_or(st.nominal_warm) }),
        }
    }

    /// As [`FkModel::eval`], with the Newton solves started from a frozen evaluation's last
    /// orientation (near `theta_deg`); same result, fewer iterations after a large move.
    pub fn eval_near(
        &self,
        st: &mut FkState,
        theta_deg: &[f64; 3],
        gravity: [f64; 3],
        near: &Frozen,
    ) -> Result<[f64; 6]> {
        match &self.kind {
            Kind::Physics { fk, residual } => {
                let stream = st.unit.get_or_insert_with(|| fk.stream());
                let mut out = fk.next_from(stream, theta_deg, gravity, &near.warm)?.to_p6();
                if let Some(n) = residual {
                    let d = n.eval(theta_deg)?;
                    for k in 0..6 {
                        out[k] += d[k];
                    }
                }
                Ok(out)
            }
            Kind::Net(_) => self.eval(st, theta_deg, gravity),
            Kind::Split { .. } => {
                st.nominal_warm = near.warm;
                self.eval(st, theta_deg, gravity)
            }
        }
    }

    /// The pose (deg, mm) at readings `theta_deg` under frozen conditions (see
    /// [`FkModel::freeze`]); the warm start follows the calls. The working mode is checked,
    /// the singularity margin is not: check the answer with [`FkModel::eval`].
    pub fn eval_frozen(&self, fr: &mut Frozen, theta_deg: &[f64; 3]) -> Result<[f64; 6]> {
        match &self.kind {
            Kind::Physics { fk, residual } => {
                let cond = fr.cond.unwrap_or_default();
                let (pose, r) = fk.pose_unchecked(theta_deg, &cond, Some(&fr.warm))?;
                fr.warm = r;
                let mut out = pose.to_p6();
                if let Some(n) = residual {
                    let d = n.eval(theta_deg)?;
                    for k in 0..6 {
                        out[k] += d[k];
                    }
                }
                Ok(out)
            }
            Kind::Net(n) => n.eval(theta_deg),
            Kind::Split { .. } => {
                let mut st = FkState { unit: None, nominal_warm: fr.warm };
                let out = self.eval(&mut st, theta_deg, [0.0, 1.0, 0.0])?;
                fr.warm = st.nominal_warm;
                Ok(out)
            }
        }
    }

    /// Whether the network runs through ONNX Runtime (float32: solvers take coarser steps).
    pub fn runs_in_float32(&self) -> bool {
        let ort = |n: &NetRunner| matches!(n, NetRunner::Ort { .. });
        match &self.kind {
            Kind::Physics { residual, .. } => residual.as_ref().is_some_and(ort),
            Kind::Net(n) => ort(n),
            Kind::Split { internal, external, .. } => ort(internal) || ort(external),
        }
    }

    /// Predictions for every sample, in acquisition order; errors name the sample.
    pub fn predict_dataset(&self, data: &Dataset) -> Result<Vec<[f64; 6]>> {
        let mut st = self.state();
        data.samples
            .iter()
            .map(|s| {
                self.eval(&mut st, &s.theta_deg, s.gravity_or_default())
                    .map_err(|e| CalibError::Data(format!("sample seq {}: {e}", s.seq)))
            })
            .collect()
    }
}
