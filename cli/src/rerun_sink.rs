//! `--rerun FILE`: the rerun logging sink when abvs is built with the `rerun` feature.
use std::path::Path;

use abvs_runtime::pipeline::Sink;
use abvs_runtime::tasks::rectify::RectifiedCamera;

#[cfg(feature = "rerun")]
pub fn open(path: &Path, cam: &RectifiedCamera) -> anyhow::Result<Box<dyn Sink>> {
    Ok(Box::new(abvs_runtime::sinks::rerun_log::RerunSink::create(path, cam)?))
}

#[cfg(not(feature = "rerun"))]
pub fn open(path: &Path, _cam: &RectifiedCamera) -> anyhow::Result<Box<dyn Sink>> {
    anyhow::bail!(
        "--rerun {}: this abvs was built without rerun support; rebuild with `cargo build --release -p abvs --features rerun`",
        path.display()
    )
}
