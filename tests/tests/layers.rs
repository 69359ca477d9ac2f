//! What runs on the robot links no offline toolkit crate (ARCHITECTURE.md). Only the workspace's own crates can
//! pull a toolkit crate in, so the check walks their manifests: from each onboard crate, the `abvs-*` crates of
//! `[dependencies]` (normal ones, optional ones included: a feature could turn them on; dev-dependencies never
//! reach the robot), recursively, must hold none of abvs-calib, abvs-render, abvs-plot, abvs-sim, abvs-paper,
//! abvs-camcal, abvs-selfcheck.
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The crates the robot never links: training, experiments, rendering, simulation, plots.
const TOOLKIT: [&str; 7] =
    ["abvs-calib", "abvs-render", "abvs-plot", "abvs-sim", "abvs-paper", "abvs-camcal", "abvs-selfcheck"];
/// The crates that run on the robot.
const ONBOARD: [&str; 8] = [
    "abvs-runtime",
    "abvs-runtime-core",
    "abvs-disparity",
    "abvs-eye",
    "abvs-fk",
    "abvs-camera",
    "abvs-onnx",
    "abvs-board",
];

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

/// Each package's normal (not dev, not build) dependencies as cargo resolved them for the workspace
/// (`cargo metadata`: the real closure, crates.io included, under the features the workspace turns on).
fn resolved_normal_graph() -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = std::process::Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--offline", "--locked"])
        .current_dir(&root)
        .output()
        .expect("cargo metadata runs");
    assert!(out.status.success(), "cargo metadata: {}", String::from_utf8_lossy(&out.stderr));
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).expect("cargo metadata's JSON");
    let name_of: BTreeMap<&str, &str> = meta["packages"]
        .as_array()
        .expect("packages")
        .iter()
        .map(|p| (p["id"].as_str().expect("id"), p["name"].as_str().expect("name")))
        .collect();
    let mut graph = BTreeMap::new();
    for node in meta["resolve"]["nodes"].as_array().expect("resolve.nodes") {
        let deps = node["deps"]
            .as_array()
            .expect("deps")
            .iter()
            .filter(|d| d["dep_kinds"].as_array().is_some_and(|k| k.iter().any(|k| k["kind"].is_null())))
            .map(|d| name_of[d["pkg"].as_str().expect("pkg")].to_string())
            .collect();
        graph.insert(name_of[node["id"].as_str().expect("id")].to_string(), deps);
    }
    graph
}

/// The runtime's whole normal dependency closure (crates.io included) holds no toolkit crate, and the bottom
/// crate's holds none of the heavy backends (OpenCV, ONNX Runtime, iceoryx2, Zenoh) nor the runtime itself.
#[test]
fn resolved_closures_hold_no_toolkit_and_core_no_backend() {
    let graph = resolved_normal_graph();
    let runtime = closure(&graph, "abvs-runtime");
    let bad: Vec<&str> = TOOLKIT.iter().copied().filter(|t| runtime.contains(*t)).collect();
    assert!(bad.is_empty(), "abvs-runtime's resolved closure holds the toolkit: {bad:?}");
    // the walk sees crates.io crates: the runtime links OpenCV and iceoryx2
    assert!(runtime.contains("opencv") && runtime.contains("iceoryx2"), "{runtime:?}");
    let core = closure(&graph, "abvs-runtime-core");
    let heavy = ["opencv", "ort", "iceoryx2", "zenoh", "abvs-runtime", "abvs-fk", "abvs-onnx", "abvs-camera"];
    let bad: Vec<&str> = heavy.iter().copied().filter(|t| core.contains(*t)).collect();
    assert!(bad.is_empty(), "abvs-runtime-core's resolved closure holds {bad:?}");
}
