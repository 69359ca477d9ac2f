//! What runs on the robot links no offline toolkit crate (ARCHITECTURE.md). Only the workspace's own crates can
//! pull a toolkit crate in, so the check walks their manifests: from each onboard crate, the `abvs-*` crates of
//! `[dependencies]` (normal ones, optional ones included: a feature could turn them on; dev-dependencies never
//! reach the robot), recursively, must hold none of abvs-calib, abvs-render, abvs-plot, abvs-sim, abvs-paper,
//! abvs-camcal.
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The crates the robot never links: training, experiments, rendering, simulation, plots.
const TOOLKIT: [&str; 6] = ["abvs-calib", "abvs-render", "abvs-plot", "abvs-sim", "abvs-paper", "abvs-camcal"];
/// The crates that run on the robot.
const ONBOARD: [&str; 6] = ["abvs-runtime", "abvs-disparity", "abvs-eye", "abvs-fk", "abvs-camera", "abvs-onnx"];

/// Each workspace crate's name and the `abvs-*` crates of its `[dependencies]`.
fn workspace_graph() -> BTreeMap<String, BTreeSet<String>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let read = |p: &Path| -> toml::Table {
        let text = std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        text.parse().unwrap_or_else(|e| panic!("{}: {e}", p.display()))
    };
    let ws = read(&root.join("Cargo.toml"));
    let members = ws["workspace"]["members"].as_array().expect("workspace.members");
    let mut graph = BTreeMap::new();
    for m in members {
        let manifest = read(&root.join(m.as_str().expect("a member path")).join("Cargo.toml"));
        let name = manifest["package"]["name"].as_str().expect("package.name").to_string();
        let deps = manifest.get("dependencies").and_then(|d| d.as_table()).cloned().unwrap_or_default();
        let ours = deps.keys().filter(|k| k.starts_with("abvs-")).cloned().collect();
        graph.insert(name, ours);
    }
    graph
}

fn closure(graph: &BTreeMap<String, BTreeSet<String>>, from: &str) -> BTreeSet<String> {
    let (mut seen, mut todo) = (BTreeSet::new(), vec![from.to_string()]);
    while let Some(c) = todo.pop() {
        if seen.insert(c.clone()) {
            todo.extend(graph.get(&c).unwrap_or_else(|| panic!("`{c}` is not a workspace crate")).iter().cloned());
        }
    }
    seen
}

#[test]
fn what_runs_on_the_robot_links_no_toolkit_crate() {
    let graph = workspace_graph();
    for crate_name in ONBOARD {
        let deps = closure(&graph, crate_name);
        let bad: Vec<&str> = TOOLKIT.iter().copied().filter(|t| deps.contains(*t)).collect();
        assert!(bad.is_empty(), "{crate_name} links the offline toolkit: {bad:?} (closure {deps:?})");
    }
    // the walk finds what is there: the program links both sides
    let cli = closure(&graph, "abvs");
    assert!(TOOLKIT.iter().all(|t| cli.contains(*t)), "the abvs program links every toolkit crate: {cli:?}");
}
