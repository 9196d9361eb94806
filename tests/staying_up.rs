//! A graph that loses a node: the run ends within seconds with an error naming that node, and
//! what the sink already wrote is whole. In a test binary of its own: the nodes are children of
//! this process, and no other test's nodes may be among them.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn graph(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("graphs")
        .join(name)
}

/// The child of this process whose command name starts with `comm` (the kernel keeps 15
/// characters of it).
fn child_named(comm: &str) -> Option<u32> {
    let me = std::process::id();
    std::fs::read_dir("/proc").ok()?.flatten().find_map(|e| {
        let pid: u32 = e.file_name().to_str()?.parse().ok()?;
        let stat = std::fs::read_to_string(e.path().join("stat")).ok()?;
        // `pid (comm) state ppid ...`; comm may hold spaces, so split after its last ')'.
        let (head, tail) = stat.rsplit_once(')')?;
        let name = head.split_once('(')?.1;
        let ppid: u32 = tail.split_whitespace().nth(1)?.parse().ok()?;
        (ppid == me && comm.starts_with(name)).then_some(pid)
    })
}

fn rows(csv: &Path) -> usize {
    std::fs::read_to_string(csv).map_or(0, |t| t.lines().count().saturating_sub(1))
}

#[test]
fn a_node_killed_mid_run_ends_the_run_within_seconds_naming_it() {
    let out = tempfile::tempdir().expect("tempdir");
    let frames = out.path().to_path_buf();
    let run = std::thread::spawn(move || {
        neuspike::graph::run(
            &graph("spike-tfp-live.yml"),
            &[
                (
                    "spike-source".to_string(),
                    "--max-planes 1200000 --scene bright-static --pace realtime".to_string(),
                ),
                (
                    "sink".to_string(),
                    format!("--out {} --write-every 10", frames.display()),
                ),
            ],
            true,
            Some(Duration::from_secs(240)),
            None,
        )
    });
    // Once frames flow (60 s of camera are queued up behind the pace), kill represent.
    let csv = out.path().join("metrics.csv");
    let start = Instant::now();
    while rows(&csv) < 300 {
        assert!(
            start.elapsed() < Duration::from_secs(180),
            "no frames after 180 s"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let pid = child_named("neuspike-represent").expect("represent is running");
    let status = std::process::Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    let killed = Instant::now();
    let report = run
        .join()
        .expect("run thread")
        .expect("the runner returned");
    let took = killed.elapsed();
    assert!(
        took < Duration::from_secs(10),
        "the run went on {took:?} after represent died"
    );
    // Only the killed node failed: the others ended on their own.
    assert_eq!(report.failed_nodes(), ["represent"]);
    let e = report.into_result().expect_err("a failed run").to_string();
    assert!(e.contains("represent"), "{e}");

    // What the sink wrote is whole: the summary, every metrics row, every PNG.
    let text = std::fs::read_to_string(out.path().join("summary.yml")).expect("summary.yml");
    let summary: neuspike_sink::report::SummaryFile = serde_yaml::from_str(&text).expect("yaml");
    let tfp = &summary.inputs["tfp"];
    let csv_text = std::fs::read_to_string(&csv).expect("metrics.csv");
    let mut pngs = 0;
    for line in csv_text.lines().skip(1) {
        let fields: Vec<&str> = line.split(',').collect();
        assert_eq!(fields.len(), 9, "a cut row: {line}");
        if !fields[8].is_empty() {
            neuspike_sink::png_out::read_frame_png(&out.path().join(fields[8]))
                .expect("a readable PNG");
            pngs += 1;
        }
    }
    assert_eq!(csv_text.lines().count() as u64 - 1, tfp.counts.received);
    assert_eq!(pngs, tfp.counts.written);
    assert!(
        tfp.counts.received >= 300 && tfp.counts.missing == 0,
        "{text}"
    );
}
