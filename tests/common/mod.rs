//! What the whole-graph tests share: the repository's root, Python's packages, and running a
//! graph that must succeed.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

/// The repository's root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether `python3` imports every module of `modules` (`"zenoh, rosbags"`); prints a notice
/// saying what to install when it does not.
pub fn python_has(modules: &str) -> bool {
    let ok = Command::new("python3")
        .args(["-c", &format!("import {modules}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        eprintln!(
            "notice: skipped: python3 cannot import {modules} (pip install pyarrow numpy \
             dora-rs==1.1.0 eclipse-zenoh==1.10.2 rosbags mcap rerun-sdk)"
        );
    }
    ok
}

/// Runs `graph` (relative to the root) with `overrides` appended to its nodes' arguments,
/// building first, and fails the test if a node failed.
pub fn run_graph(graph: &str, overrides: &[(&str, String)]) -> neuspike::graph::Report {
    let overrides: Vec<(String, String)> = overrides
        .iter()
        .map(|(id, args)| (id.to_string(), args.clone()))
        .collect();
    let report = neuspike::graph::run(
        &root().join(graph),
        &overrides,
        true,
        Some(Duration::from_secs(300)),
        None,
    )
    .unwrap_or_else(|e| panic!("{graph}: {e:#}"));
    assert!(report.failures.is_empty(), "{graph}: {:?}", report.failures);
    report
}
