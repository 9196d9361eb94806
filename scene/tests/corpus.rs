//! The `scene` fuzz target's committed corpus (`fuzz/corpus-min/scene/`), replayed through the
//! target's checks (`fuzz/src/scene.rs`) without libFuzzer: any scene YAML builds or is refused
//! without a panic, and one that builds renders finite, non-negative pixels.

#[path = "../../fuzz/src/scene.rs"]
mod checks;

#[test]
fn every_committed_scene_input_passes_the_targets_checks() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus-min/scene");
    let mut replayed = 0;
    for entry in std::fs::read_dir(&dir).expect("the committed corpus") {
        let path = entry.expect("entry").path();
        let data = std::fs::read(&path).expect("read");
        let outcome = std::panic::catch_unwind(|| checks::scene(&data));
        assert!(outcome.is_ok(), "{} fails the checks", path.display());
        replayed += 1;
    }
    assert!(replayed > 0, "no corpus under {}", dir.display());
}
