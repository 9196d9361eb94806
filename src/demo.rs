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
    graph::write_built_in(DEMO_GRAPH, &out, "neuspike demo", |id, args| match id {
        "spike-source" | "event-source" => Some(format!("{args} --scene {scene_arg}")),
        "sink" => Some(format!("{args} --out {}", out.display())),
        _ => None,
    })
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
