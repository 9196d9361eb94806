//! The layers of the workspace, read from its manifests: the algorithm libraries (`stages/`) and
//! every library but the runtime know nothing of dora; a node (`nodes/`, `examples/`) is a thin
//! binary over libraries and the runtime, and no node depends on another. `cargo tree --workspace
//! -i dora-node-api -e normal --depth 1` shows the same.

use std::path::{Path, PathBuf};

/// A workspace member: its folder, its name and the names of its normal dependencies.
struct Member {
    path: String,
    name: String,
    deps: Vec<String>,
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The lines of `section` (`[dependencies]`) of a manifest.
fn section<'t>(text: &'t str, section: &str) -> Vec<&'t str> {
    let mut inside = false;
    let mut out = Vec::new();
    for line in text.lines() {
        let l = line.trim();
        if l.starts_with('[') {
            inside = l == section;
            continue;
        }
        if inside && !l.is_empty() && !l.starts_with('#') {
            out.push(l);
        }
    }
    out
}

fn members() -> Vec<Member> {
    let text = std::fs::read_to_string(root().join("Cargo.toml")).expect("Cargo.toml");
    let list = text
        .split_once("members = [")
        .and_then(|(_, rest)| rest.split_once(']'))
        .map(|(list, _)| list)
        .expect("a members list");
    let mut out = vec![member(&root(), ".")];
    for path in list.split(',').map(|p| p.trim().trim_matches('"')) {
        if !path.is_empty() {
            out.push(member(&root().join(path), path));
        }
    }
    out
}

fn member(dir: &Path, path: &str) -> Member {
    let text = std::fs::read_to_string(dir.join("Cargo.toml")).expect("a manifest");
    let name = section(&text, "[package]")
        .into_iter()
        .find_map(|l| l.strip_prefix("name = "))
        .map(|n| n.trim_matches('"').to_string())
        .expect("a package name");
    let deps = section(&text, "[dependencies]")
        .into_iter()
        .filter_map(|l| l.split(['.', '=', ' ']).next())
        .map(String::from)
        .collect();
    Member {
        path: path.to_string(),
        name,
        deps,
    }
}

fn is_node(m: &Member) -> bool {
    m.path.starts_with("nodes/") || m.path.starts_with("examples/")
}

#[test]
fn only_the_runtime_the_program_and_the_nodes_link_dora() {
    let all = members();
    assert!(all.len() > 20, "{} members", all.len());
    for m in &all {
        let dora = m
            .deps
            .iter()
            .any(|d| d == "dora-node-api" || d == "neuspike-runtime");
        let allowed = is_node(m) || m.name == "neuspike-runtime" || m.name == "neuspike";
        assert!(
            !dora || allowed,
            "{} ({}) is a library and depends on dora or the runtime",
            m.name,
            m.path
        );
    }
}

#[test]
fn no_node_depends_on_another_and_every_stage_has_its_node() {
    let all = members();
    let nodes: Vec<&Member> = all.iter().filter(|m| is_node(m)).collect();
    for n in &nodes {
        for d in &n.deps {
            assert!(
                !nodes.iter().any(|o| o.name == *d),
                "node {} depends on node {d}",
                n.name
            );
        }
    }
    for stage in all.iter().filter(|m| m.path.starts_with("stages/")) {
        // A library is named for what it computes; its stage is named for its place in a graph.
        let kind = match stage.path.trim_start_matches("stages/") {
            "spike-camera" => "spike-source",
            "event-camera" => "event-source",
            "representations" => "represent",
            "reconstruction" => "infer",
            other => other,
        };
        let node = all
            .iter()
            .find(|m| m.path == format!("nodes/{kind}"))
            .unwrap_or_else(|| panic!("{}: no node nodes/{kind}", stage.name));
        assert!(
            node.deps.contains(&stage.name),
            "{} does not run {}",
            node.name,
            stage.name
        );
        let manifest =
            std::fs::read_to_string(root().join(&node.path).join("Cargo.toml")).expect("manifest");
        assert!(
            manifest.contains(&format!("name = \"neuspike-{kind}\"")),
            "{}: its binary is not neuspike-{kind}",
            node.name
        );
    }
}

/// The Python package's native part is built on the dora-free libraries: what `cargo tree`
/// resolves for it (its own features, as maturin builds it) holds neither dora nor zenoh.
#[test]
fn the_python_package_links_neither_dora_nor_zenoh() {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args([
            "tree",
            "--offline",
            "-p",
            "neuspike-python",
            "-e",
            "normal",
            "--prefix",
            "none",
        ])
        .current_dir(root())
        .output()
        .expect("cargo tree runs");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let crates: Vec<&str> = text.lines().filter_map(|l| l.split(' ').next()).collect();
    for needed in ["neuspike-formats", "neuspike-representations", "pyo3"] {
        assert!(
            crates.contains(&needed),
            "{needed} is not in the tree:\n{text}"
        );
    }
    let network: Vec<&&str> = crates
        .iter()
        .filter(|c| c.starts_with("dora") || c.starts_with("zenoh") || **c == "neuspike-net")
        .collect();
    assert!(network.is_empty(), "the Python package links {network:?}");
}
