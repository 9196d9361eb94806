//! The `ros2_cdr` fuzz target's committed corpus (`fuzz/corpus-min/ros2_cdr/`), replayed through
//! the target's checks (`fuzz/src/ros2.rs`) without libFuzzer: ROS 2 samples parse or give an
//! error without a panic, and the packet decoder's batches hold valid events that tile time.

#[path = "../../../fuzz/src/ros2.rs"]
mod checks;

#[test]
fn every_committed_ros2_input_passes_the_targets_checks() {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus-min/ros2_cdr");
    let mut replayed = 0;
    for entry in std::fs::read_dir(&dir).expect("the committed corpus") {
        let path = entry.expect("entry").path();
        let data = std::fs::read(&path).expect("read");
        let outcome = std::panic::catch_unwind(|| checks::ros2_cdr(&data));
        assert!(outcome.is_ok(), "{} fails the checks", path.display());
        replayed += 1;
    }
    assert!(replayed > 0, "no corpus under {}", dir.display());
}
