//! The `graph` fuzz target's committed corpus (`fuzz/corpus-min/graph/`), replayed through the
//! target's checks (`fuzz/src/graph.rs`) without libFuzzer.

#[path = "../../fuzz/src/graph.rs"]
mod checks;

#[test]
fn every_committed_graph_input_passes_the_targets_checks() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus-min/graph");
    let mut replayed = 0;
    for entry in std::fs::read_dir(&dir).expect("the committed corpus") {
        let path = entry.expect("entry").path();
        let data = std::fs::read(&path).expect("read");
        let outcome = std::panic::catch_unwind(|| checks::graph(&data));
        assert!(outcome.is_ok(), "{} fails the checks", path.display());
        replayed += 1;
    }
    assert!(replayed > 0, "no corpus under {}", dir.display());
}
