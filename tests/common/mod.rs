//! What the whole-graph tests share: the repository's root, Python's packages, running a graph
//! that must succeed, and the paper's rig of two sensors.

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

/// The paper's rig: a DAVIS346 beside a 400x250 spike camera, its frame 1.16x the spike pitch
/// across and 0.96x down (the two views the same size), turned half a degree, shifted a pixel:
/// DAVIS346 pixel -> spike pixel.
pub fn davis346_rig() -> neuspike_geometry::Homography {
    turned_rig((400.0 / 346.0, 250.0 / 260.0), 0.5, (1.0, -1.0))
}

/// An event camera pixel -> spike pixel mapping: the pitch scaled by `(sx, sy)`, turned by `deg`
/// degrees, shifted by `(dx, dy)` spike pixels.
pub fn turned_rig(
    (sx, sy): (f64, f64),
    deg: f64,
    (dx, dy): (f64, f64),
) -> neuspike_geometry::Homography {
    let a = deg.to_radians();
    neuspike_geometry::Homography::new([
        sx * a.cos(),
        -sy * a.sin(),
        dx,
        sx * a.sin(),
        sy * a.cos(),
        dy,
        0.0,
        0.0,
        1.0,
    ])
    .expect("the rig's homography")
}
