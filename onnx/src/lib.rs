//! ONNX Runtime for abvs: finds the shared library, loads it once, opens sessions.
//!
//! ort is built with `load-dynamic`, so the library is found at run time. Search order (the
//! first existing file wins):
//! 1. `$ABVS_ORT_DYLIB` (a file), then `$ORT_DYLIB_PATH` (ort's own variable);
//! 2. next to the executable: `<exe dir>/libonnxruntime.so*`, `<exe dir>/../lib/libonnxruntime.so*`;
//! 3. the checkout's `.deps/onnxruntime/`, where `scripts/setup.sh` unpacks it (the path is
//!    fixed when abvs is built, so a built `abvs` needs no variable);
//! 4. `/usr/local/lib`, `/usr/lib/x86_64-linux-gnu`, `/usr/lib`.
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The ONNX Runtime release abvs is built and tested against.
pub const ORT_VERSION: &str = "1.31.1";

#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error("ONNX Runtime library not found; looked in: {searched}. Run scripts/setup.sh or set ABVS_ORT_DYLIB to the path of libonnxruntime.so.{ORT_VERSION}")]
    NotFound { searched: String },
    #[error("{var} points to {path}, which does not exist")]
    BadVariable { var: &'static str, path: PathBuf },
    #[error("loading ONNX Runtime from {path}: {msg}")]
    Load { path: PathBuf, msg: String },
    #[error("ONNX model {path}: {msg}")]
    Model { path: PathBuf, msg: String },
}

pub type Result<T> = std::result::Result<T, OnnxError>;

const NAMES: [&str; 2] = ["libonnxruntime.so.1.31.1", "libonnxruntime.so"];

/// Candidate locations in search order (see the crate doc).
pub fn candidates() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        if let Some(d) = exe.parent() {
            dirs.push(d.to_path_buf());
            dirs.push(d.join("../lib"));
        }
    }
    dirs.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("../.deps/onnxruntime"));
    for d in ["/usr/local/lib", "/usr/lib/x86_64-linux-gnu", "/usr/lib"] {
        dirs.push(PathBuf::from(d));
    }
    dirs.iter().flat_map(|d| NAMES.iter().map(move |n| d.join(n))).collect()
}

/// Where the library is, following the search order.
pub fn find_library() -> Result<PathBuf> {
    for var in ["ABVS_ORT_DYLIB", "ORT_DYLIB_PATH"] {
        if let Some(v) = std::env::var_os(var).filter(|v| !v.is_empty()) {
            let p = PathBuf::from(v);
            return if p.is_file() { Ok(p) } else { Err(OnnxError::BadVariable { var, path: p }) };
        }
    }
    let c = candidates();
    c.iter().find(|p| p.is_file()).cloned().ok_or_else(|| OnnxError::NotFound {
        searched: c.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "),
    })
}

/// What was loaded.
#[derive(Clone)]
pub struct RuntimeInfo {
    pub path: PathBuf,
    pub build_info: String,
    /// The process-wide environment sessions are created in.
    pub env: ort::environment::Environment,
}

static RUNTIME: OnceLock<std::result::Result<RuntimeInfo, String>> = OnceLock::new();

/// Loads ONNX Runtime once per process (later calls return the same result).
pub fn init() -> Result<&'static RuntimeInfo> {
    let r = RUNTIME.get_or_init(|| {
        let path = find_library().map_err(|e| e.to_string())?;
        let builder = ort::init_from(&path).map_err(|e| format!("loading {}: {e}", path.display()))?;
        let env = builder.with_name("abvs").build().map_err(|e| format!("creating the environment: {e}"))?;
        Ok(RuntimeInfo { build_info: ort::info().to_string(), path, env })
    });
    r.as_ref().map_err(|msg| OnnxError::Load { path: PathBuf::from("(search order)"), msg: msg.clone() })
}

/// Opens a model with `threads` intra-op threads (runtime init included).
pub fn session(path: &Path, threads: usize) -> Result<ort::session::Session> {
    let rt = init()?;
    let err = |e: ort::Error| OnnxError::Model { path: path.to_path_buf(), msg: e.to_string() };
    if !path.is_file() {
        // say what is there: /dev/null exists, it is just not a model file
        let msg = match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => "no such file".into(),
            Err(e) => e.to_string(),
            Ok(m) if m.is_dir() => "is a directory, expected an .onnx file".into(),
            Ok(_) => "not a regular file (a device, pipe or socket), expected an .onnx file".into(),
        };
        return Err(OnnxError::Model { path: path.to_path_buf(), msg });
    }
    ort::session::Session::builder(&rt.env)
        .map_err(err)?
        .with_intra_threads(threads)
        .map_err(|e| OnnxError::Model { path: path.to_path_buf(), msg: e.to_string() })?
        // Idle intra-op threads sleep instead of spinning: on the robot's few cores the other lanes
        // (rectification, census refinement, publishing) need the CPU a spinning pool burns. Measured
        // on the fixture, lossless, 2 cores under load: 2.9 s of CPU for 50 frames against 4.7 s spinning.
        .with_intra_op_spinning(false)
        .map_err(|e| OnnxError::Model { path: path.to_path_buf(), msg: e.to_string() })?
        .commit_from_file(path)
        .map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_and_loads_the_installed_runtime() {
        let info = init().expect("ONNX Runtime installed by scripts/setup.sh");
        assert!(info.path.is_file());
        assert!(info.build_info.starts_with("ORT Build Info"), "{}", info.build_info);
        // The loaded library answers real API calls: the runtime is usable, not just found.
        let ok = ort::session::Session::builder(&info.env).is_ok();
        assert!(ok);
    }

    #[test]
    fn missing_model_is_a_clear_error() {
        let e = session(Path::new("/nonexistent/model.onnx"), 1).unwrap_err().to_string();
        assert!(e.contains("/nonexistent/model.onnx"), "{e}");
    }
}
