//! The fuzz targets' committed corpus (`fuzz/corpus-min/<target>/`: small inputs that cover the
//! decoders' paths, findings included), replayed through the same checks the targets make
//! (`fuzz/src/formats.rs`), without libFuzzer: a decoder that panics, delivers an event outside
//! its sensor or out of order, or breaks a count on any of them fails here.

#[path = "../../fuzz/src/formats.rs"]
#[allow(dead_code)]
mod checks;

use std::path::Path;

/// A target's checks.
type Check = fn(&[u8]);

const TARGETS: [(&str, Check); 8] = [
    ("raw", checks::raw),
    ("prophesee_dat", checks::prophesee_dat),
    ("text", checks::text),
    ("aedat4", checks::aedat4),
    ("pku", checks::pku),
    ("sniff", checks::sniff),
    ("npy", checks::npy),
    ("npy_file", checks::npy_file),
];

#[test]
fn every_committed_input_passes_its_targets_checks() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus-min");
    let mut replayed = 0;
    for (target, check) in TARGETS {
        let dir = root.join(target);
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries {
            let path = entry.expect("entry").path();
            let data = std::fs::read(&path).expect("read");
            let outcome = std::panic::catch_unwind(|| check(&data));
            assert!(
                outcome.is_ok(),
                "{target}: {} fails its checks",
                path.display()
            );
            replayed += 1;
        }
    }
    assert!(replayed > 0, "no corpus under {}", root.display());
}
