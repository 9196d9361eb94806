//! `neuspike demo`: the default graph on a built-in scene, written into a folder of the current
//! directory with everything it needs, and run there.

use std::path::{Path, PathBuf};

use eyre::WrapErr;

use crate::graph;

/// The default graph (`graphs/demo.yml`), built into the program.
pub const DEMO_GRAPH: &str = include_str!("../graphs/demo.yml");

/// What a demo run writes in its folder, cleared before each run so that a failed run never
/// shows an earlier run's results as its own.
const PRODUCTS: [&str; 8] = [
    "summary.md",
    "summary.yml",
    "metrics.csv",
    "graph.yml",
    "types",
    "tfp",
    "tfi",
    "ground-truth",
];

/// Writes the demo graph into `out` (its frames, metrics and summary go there too), the scene
/// set to `scene` (a built-in name, or a scene file made absolute), its nodes the binaries beside
/// this program, and the message types beside it; clears what an earlier run wrote there.
/// Returns the graph's path.
pub fn prepare(out: &Path, scene: &str) -> eyre::Result<PathBuf> {
    let scene_arg = if neuspike_scene::Scene::builtin_names().contains(&scene) {
        scene.to_string()
    } else {
        std::fs::canonicalize(scene)
            .wrap_err_with(|| format!("scene `{scene}` is neither built in nor a readable file"))?
            .display()
            .to_string()
    };
    std::fs::create_dir_all(out)
        .wrap_err_with(|| format!("cannot create the output folder {}", out.display()))?;
    let out = out.canonicalize()?;
    for name in PRODUCTS {
        let p = out.join(name);
        let gone = if p.is_dir() {
            std::fs::remove_dir_all(&p)
        } else if p.exists() {
            std::fs::remove_file(&p)
        } else {
            Ok(())
        };
        gone.wrap_err_with(|| format!("cannot clear {} from an earlier run", p.display()))?;
    }
    let mut g: serde_yaml::Value =
        serde_yaml::from_str(DEMO_GRAPH).wrap_err("the built-in demo graph is not YAML")?;
    let nodes = g
        .get_mut("nodes")
        .and_then(serde_yaml::Value::as_sequence_mut);
    for node in nodes.into_iter().flatten() {
        let Some(map) = node.as_mapping_mut() else {
            continue;
        };
        // Built by `run` beforehand when the program runs from its sources; never from here.
        map.remove("build");
        let args = map
            .get("args")
            .and_then(serde_yaml::Value::as_str)
            .unwrap_or("")
            .to_string();
        let id = map
            .get("id")
            .and_then(serde_yaml::Value::as_str)
            .unwrap_or("");
        let args = match id {
            "spike-source" | "event-source" => format!("{args} --scene {scene_arg}"),
            "sink" => format!("{args} --out {}", out.display()),
            _ => continue,
        };
        map.insert("args".into(), args.into());
    }
    // The graph's relative paths mean nothing in `out`: every node runs the binary beside this
    // program, and a missing one is an error saying how to build it.
    graph::resolve_node_binaries(&mut g, &out)?;
    graph::write_types(&out)?;
    let path = out.join("graph.yml");
    let text = serde_yaml::to_string(&g).wrap_err("cannot write the demo graph")?;
    std::fs::write(&path, format!("# Written by `neuspike demo`.\n{text}"))
        .wrap_err_with(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_graph_is_the_shipped_one_and_runs_where_it_is_written() {
        let shipped =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/graphs/demo.yml"))
                .expect("graphs/demo.yml");
        assert_eq!(DEMO_GRAPH, shipped);
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("demo");
        std::fs::create_dir_all(out.join("tfp")).expect("mkdir");
        std::fs::write(out.join("summary.md"), "an earlier run").expect("write");
        std::fs::write(out.join("notes.txt"), "the user's").expect("write");
        // Node binaries may not be built when the library's tests run: then the error says how.
        match prepare(&out, "dark-slow") {
            Ok(path) => {
                let text = std::fs::read_to_string(&path).expect("graph");
                assert!(!text.contains("build:"), "{text}");
                assert!(text.contains("--scene dark-slow"), "{text}");
                assert!(text.contains(&format!(
                    "--out {}",
                    out.canonicalize().expect("out").display()
                )));
                assert!(out.join("types/neuspike/messages/v1.yml").is_file());
            }
            Err(e) => assert!(e.to_string().contains("cargo build --release"), "{e}"),
        }
        assert!(!out.join("summary.md").exists() && !out.join("tfp").exists());
        assert!(
            out.join("notes.txt").exists(),
            "only the demo's own products are cleared"
        );
        let e = prepare(&out, "no-such-scene").unwrap_err().to_string();
        assert!(e.contains("no-such-scene"), "{e}");
    }
}
