//! The layering ARCHITECTURE.md writes down ("Layers"), checked from the source: every library crate's modules
//! import one way (no circle between the modules of one parent, at any depth), the modules of a crate with a
//! written order import only from their layer or below, and every crate depends only on crates of lower layers.
//! Imports are read from the text: `use` trees and every `crate::` / `super::` / `self::` path, comments and
//! `#[cfg(test)]` modules left out (a test may reach anywhere).
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// Workspace members: (package name, directory).
fn members() -> Vec<(String, PathBuf)> {
    let ws: toml::Table = read(&root().join("Cargo.toml")).parse().expect("Cargo.toml");
    let list = ws["workspace"]["members"].as_array().expect("workspace.members");
    list.iter()
        .map(|m| {
            let dir = root().join(m.as_str().expect("a member path"));
            let manifest: toml::Table = read(&dir.join("Cargo.toml")).parse().expect("a member's Cargo.toml");
            (manifest["package"]["name"].as_str().expect("package.name").to_string(), dir)
        })
        .collect()
}

/// The layer lines of ARCHITECTURE.md's ```layers block: `name: a b < c < d e` -> name -> [[a, b], [c], [d, e]].
fn written_layers() -> BTreeMap<String, Vec<Vec<String>>> {
    let text = read(&root().join("ARCHITECTURE.md"));
    let start = text.find("```layers\n").expect("ARCHITECTURE.md has a ```layers block") + "```layers\n".len();
    let end = start + text[start..].find("```").expect("the layers block ends");
    text[start..end]
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let (name, order) = l.split_once(':').unwrap_or_else(|| panic!("layers line without `name:`: {l}"));
            let layers = order.split('<').map(|g| g.split_whitespace().map(String::from).collect()).collect();
            (name.trim().to_string(), layers)
        })
        .collect()
}

fn layer_of(layers: &[Vec<String>], name: &str) -> Option<usize> {
    layers.iter().position(|g| g.iter().any(|n| n == name))
}

/// Removes comments (line and block) and string literals' contents, keeping line structure irrelevant.
fn strip(src: &str) -> String {
    let b = src.as_bytes();
    let (mut out, mut i) = (String::with_capacity(src.len()), 0);
    while i < b.len() {
        if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
            i += 2;
            while i + 1 < b.len() && !(b[i] == b'*' && b[i + 1] == b'/') {
                i += 1;
            }
            i += 2;
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if b[i] == b'\'' && b.get(i + 2) == Some(&b'\'') {
            // a char literal such as '{' (lifetimes have no closing quote two bytes on)
            i += 3;
        } else {
            let c = src[i..].chars().next().expect("a char");
            out.push(c);
            i += c.len_utf8();
        }
    }
    out
}

/// Drops every `#[cfg(test)]` item whose body is a `{ ... }` block (the test modules).
fn drop_tests(src: &str) -> String {
    let mut s = src.to_string();
    while let Some(at) = s.find("#[cfg(test)]") {
        let Some(open) = s[at..].find('{').map(|o| at + o) else { break };
        let (mut depth, mut end) = (0usize, s.len());
        for (k, c) in s[open..].char_indices() {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = open + k + 1;
                        break;
                    }
                }
                _ => {}
            }
        }
        // a `#[cfg(test)] use ...;` ends at its semicolon, before any brace of the next item
        let end = match s[at..open].find(';') {
            Some(semi) => at + semi + 1,
            None => end,
        };
        s.replace_range(at..end, "");
    }
    s
}

/// The leaf paths of a `use` tree (`a::{b, c::d}` -> `a::b`, `a::c::d`).
fn flatten(prefix: &str, tree: &str, out: &mut Vec<String>) {
    let tree = tree.trim();
    let join = |p: &str, t: &str| if p.is_empty() { t.to_string() } else { format!("{p}::{t}") };
    if let Some(inner) = tree.strip_prefix('{').and_then(|t| t.strip_suffix('}')) {
        let (mut depth, mut from) = (0, 0);
        for (k, c) in inner.char_indices() {
            match c {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    flatten(prefix, &inner[from..k], out);
                    from = k + 1;
                }
                _ => {}
            }
        }
        flatten(prefix, &inner[from..], out);
    } else if let Some(brace) = tree.find("::{") {
        flatten(&join(prefix, &tree[..brace]), &tree[brace + 2..], out);
    } else if !tree.is_empty() {
        let path = tree.split_whitespace().next().expect("a path");
        out.push(join(prefix, path));
    }
}

/// The paths a module's source names: its `use` trees' leaves and every other `crate::`/`super::`/`self::` path.
fn named_paths(src: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = String::new();
    let mut s = src;
    while let Some(at) = s.find("use ") {
        let word_start = at == 0 || !s.as_bytes()[at - 1].is_ascii_alphanumeric() && s.as_bytes()[at - 1] != b'_';
        let Some(semi) = s[at..].find(';').map(|k| at + k) else { break };
        rest.push_str(&s[..at]);
        if word_start && !s[at..semi].contains('(') {
            flatten("", &s[at + 4..semi], &mut out);
            s = &s[semi + 1..];
        } else {
            rest.push_str(&s[at..at + 4]);
            s = &s[at + 4..];
        }
    }
    rest.push_str(s);
    for key in ["crate::", "super::", "self::"] {
        for (at, _) in rest.match_indices(key) {
            let before = rest[..at].chars().next_back();
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let path: String =
                rest[at..].chars().take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':').collect();
            out.push(path.trim_end_matches(':').to_string());
        }
    }
    out
}

/// One crate's modules (path from the crate root, [] for lib.rs) and, per module, the absolute paths it names
/// inside the crate.
fn crate_modules(dir: &Path) -> BTreeMap<Vec<String>, Vec<Vec<String>>> {
    let src = dir.join("src");
    let mut files = Vec::new();
    let mut todo = vec![src.clone()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())) {
            let p = e.expect("a directory entry").path();
            if p.is_dir() {
                todo.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                files.push(p);
            }
        }
    }
    let mut modules = BTreeMap::new();
    for f in files {
        let rel = f.strip_prefix(&src).expect("under src").with_extension("");
        let mut m: Vec<String> = rel.iter().map(|c| c.to_string_lossy().into_owned()).collect();
        if m.last().is_some_and(|l| l == "mod") || m == ["lib"] {
            m.pop();
        }
        if m.first().is_some_and(|f| f == "main" || f == "bin") {
            continue;
        }
        let text = drop_tests(&strip(&read(&f)));
        let refs = named_paths(&text)
            .into_iter()
            .filter_map(|p| {
                let segs: Vec<&str> = p.split("::").collect();
                let mut abs: Vec<String> = match segs[0] {
                    "crate" => Vec::new(),
                    "self" => m.clone(),
                    "super" => m[..m.len().saturating_sub(1)].to_vec(),
                    _ => return None,
                };
                let mut rest = &segs[1..];
                while rest.first() == Some(&"super") {
                    abs.pop();
                    rest = &rest[1..];
                }
                abs.extend(rest.iter().map(|s| s.to_string()));
                Some(abs)
            })
            .collect();
        modules.insert(m, refs);
    }
    modules
}

/// Edges between sibling modules (children of one parent, at every depth): module `a` names something under
/// sibling `b`. Imports from a module's own ancestors (its parent's items) are not edges: a parent and its
/// children are one unit.
fn sibling_edges(modules: &BTreeMap<Vec<String>, Vec<Vec<String>>>) -> BTreeSet<(Vec<String>, Vec<String>)> {
    let mut edges = BTreeSet::new();
    for (m, refs) in modules {
        for r in refs {
            let k = m.iter().zip(r).take_while(|(a, b)| a == b).count();
            if k < m.len() && k < r.len() {
                let (a, b) = (m[..=k].to_vec(), r[..=k].to_vec());
                if modules.contains_key(&b) {
                    edges.insert((a, b));
                }
            }
        }
    }
    edges
}

/// Strongly connected components with more than one module (Tarjan).
fn circles(edges: &BTreeSet<(Vec<String>, Vec<String>)>) -> Vec<BTreeSet<String>> {
    let nodes: BTreeSet<&Vec<String>> = edges.iter().flat_map(|(a, b)| [a, b]).collect();
    let nodes: Vec<&Vec<String>> = nodes.into_iter().collect();
    let id = |n: &Vec<String>| nodes.iter().position(|x| *x == n).expect("a node");
    let mut adj = vec![Vec::new(); nodes.len()];
    for (a, b) in edges {
        adj[id(a)].push(id(b));
    }
    struct T {
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on: Vec<bool>,
        stack: Vec<usize>,
        next: usize,
        out: Vec<Vec<usize>>,
    }
    fn visit(v: usize, adj: &[Vec<usize>], t: &mut T) {
        t.index[v] = Some(t.next);
        t.low[v] = t.next;
        t.next += 1;
        t.stack.push(v);
        t.on[v] = true;
        for &w in &adj[v] {
            match t.index[w] {
                None => {
                    visit(w, adj, t);
                    t.low[v] = t.low[v].min(t.low[w]);
                }
                Some(iw) if t.on[w] => t.low[v] = t.low[v].min(iw),
                _ => {}
            }
        }
        if Some(t.low[v]) == t.index[v] {
            let mut comp = Vec::new();
            while let Some(w) = t.stack.pop() {
                t.on[w] = false;
                comp.push(w);
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                t.out.push(comp);
            }
        }
    }
    let n = nodes.len();
    let mut t =
        T { index: vec![None; n], low: vec![0; n], on: vec![false; n], stack: Vec::new(), next: 0, out: vec![] };
    for v in 0..n {
        if t.index[v].is_none() {
            visit(v, &adj, &mut t);
        }
    }
    t.out.iter().map(|c| c.iter().map(|&i| nodes[i].join("::")).collect()).collect()
}

/// Circles known and not yet taken apart (listed exactly: the test fails if one is no longer there, so that its
/// line goes when the fix lands). None: the disparity engines moved into abvs-disparity, the encoder stream and
/// the board into abvs-board.
const PENDING_CIRCLES: [(&str, &[&str]); 0] = [];

#[test]
fn no_import_circle_and_no_import_against_the_layers() {
    let layers = written_layers();
    let mut faults = Vec::new();
    let mut pending: BTreeSet<(String, BTreeSet<String>)> =
        PENDING_CIRCLES.iter().map(|(c, ms)| (c.to_string(), ms.iter().map(|m| m.to_string()).collect())).collect();
    let mut checked = 0;
    for (name, dir) in members() {
        if !dir.join("src/lib.rs").exists() {
            continue;
        }
        checked += 1;
        let modules = crate_modules(&dir);
        let edges = sibling_edges(&modules);
        for c in circles(&edges) {
            if !pending.remove(&(name.clone(), c.clone())) {
                faults.push(format!("{name}: import circle between {c:?}"));
            }
        }
        let Some(order) = layers.get(&name) else { continue };
        let top: BTreeSet<&String> = modules.keys().filter(|m| m.len() == 1).map(|m| &m[0]).collect();
        for m in &top {
            if layer_of(order, m).is_none() {
                faults.push(format!("{name}: module `{m}` has no layer in ARCHITECTURE.md"));
            }
        }
        for (a, b) in edges.iter().filter(|(a, _)| a.len() == 1) {
            if let (Some(la), Some(lb)) = (layer_of(order, &a[0]), layer_of(order, &b[0])) {
                if lb > la {
                    faults.push(format!("{name}: `{}` (layer {}) imports `{}` (layer {})", a[0], la + 1, b[0], lb + 1));
                }
            }
        }
    }
    for (c, ms) in pending {
        faults.push(format!("{c}: the pending circle {ms:?} is gone: remove it from PENDING_CIRCLES"));
    }
    assert!(checked >= 10, "only {checked} library crates found");
    assert!(faults.is_empty(), "{}", faults.join("\n"));
}

#[test]
fn crates_depend_only_on_lower_layers() {
    let layers = written_layers();
    let order = layers.get("crates").expect("a `crates:` line in the layers block");
    let mut faults = Vec::new();
    for (name, dir) in members() {
        let Some(mine) = layer_of(order, &name) else {
            faults.push(format!("crate {name} has no layer in ARCHITECTURE.md"));
            continue;
        };
        let manifest: toml::Table = read(&dir.join("Cargo.toml")).parse().expect("Cargo.toml");
        let deps = manifest.get("dependencies").and_then(|d| d.as_table()).cloned().unwrap_or_default();
        for dep in deps.keys().filter(|d| d.starts_with("abvs")) {
            match layer_of(order, dep) {
                Some(l) if l < mine => {}
                l => {
                    faults.push(format!("{name} (layer {}) depends on {dep} (layer {:?})", mine + 1, l.map(|l| l + 1)))
                }
            }
        }
    }
    assert!(faults.is_empty(), "{}", faults.join("\n"));
}

/// The checks find what they look for: a circle, an upward import, a `use` tree, a `super` path.
#[test]
fn the_checks_see_circles_and_paths() {
    let mut out = Vec::new();
    flatten("", "crate::{a::{b, c as d}, e}", &mut out);
    assert_eq!(out, ["crate::a::b", "crate::a::c", "crate::e"]);
    let src = drop_tests(&strip(
        "use super::x::Y; // crate::not_this\nfn f() { crate::z::g(\"crate::nor_this\"); }\n#[cfg(test)]\nmod tests { use crate::t; }",
    ));
    assert_eq!(named_paths(&src), ["super::x::Y", "crate::z::g"]);
    let v = |s: &str| s.split("::").map(String::from).collect::<Vec<_>>();
    let modules: BTreeMap<Vec<String>, Vec<Vec<String>>> = [
        (v("a"), vec![v("b::f")]),
        (v("b"), vec![v("c::X")]),
        (v("c"), vec![v("a::Y")]),
        (v("c::d"), vec![v("c::e::Z"), v("c::W")]),
        (v("c::e"), vec![]),
    ]
    .into_iter()
    .collect();
    let edges = sibling_edges(&modules);
    assert!(edges.contains(&(v("c::d"), v("c::e"))) && !edges.iter().any(|(_, b)| *b == v("c::W")));
    assert_eq!(circles(&edges), vec![["a", "b", "c"].map(String::from).into_iter().collect::<BTreeSet<_>>()]);
    let order = vec![vec!["a".to_string()], vec!["b".to_string()]];
    assert!(layer_of(&order, "b") > layer_of(&order, "a"));
}
