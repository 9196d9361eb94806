//! The `policy` fuzz target's committed corpus (`fuzz/corpus-min/policy/`), replayed through the
//! target's checks (`fuzz/src/policy.rs`) without libFuzzer.

#[path = "../../../fuzz/src/policy.rs"]
mod checks;

#[test]
fn every_committed_policy_input_passes_the_targets_checks() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus-min/policy");
    let mut replayed = 0;
    for entry in std::fs::read_dir(&dir).expect("the committed corpus") {
        let path = entry.expect("entry").path();
        let data = std::fs::read(&path).expect("read");
        let outcome = std::panic::catch_unwind(|| checks::policy(&data));
        assert!(outcome.is_ok(), "{} fails the checks", path.display());
        replayed += 1;
    }
    assert!(replayed > 0, "no corpus under {}", dir.display());
}
