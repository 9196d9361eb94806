//! A graph that loses a node: the run ends within seconds with an error naming that node, and
//! what the sink already wrote is whole. In a test binary of its own: the nodes are children of
//! this process, and no other test's nodes may be among them.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// One test at a time: each finds its nodes among this process's children by name.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn graph(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("graphs")
        .join(name)
}

/// The node `name` (`neuspike-represent`) among this process's children.
fn child_named(name: &str) -> Option<u32> {
    neuspike::soak::node_children()
        .into_iter()
        .find_map(|(pid, n)| (n == name).then_some(pid))
}

fn rows(csv: &Path) -> usize {
    std::fs::read_to_string(csv).map_or(0, |t| t.lines().count().saturating_sub(1))
}

#[test]
fn a_node_killed_mid_run_ends_the_run_within_seconds_naming_it() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
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
            neuspike_image::read_frame_png(&out.path().join(fields[8])).expect("a readable PNG");
            pngs += 1;
        }
    }
    assert_eq!(csv_text.lines().count() as u64 - 1, tfp.counts.received);
    assert_eq!(pngs, tfp.counts.written);
    assert!(
        tfp.counts.received >= 300 && tfp.counts.missing == 0,
        "{text}"
    );
    // The cut reaches the sink: infer ended its stream marked as cut short.
    assert!(tfp.counts.cut, "{text}");
}

/// With `restart_policy: on-failure`, dora restarts a source killed mid-run; the new process
/// resumes on the camera's clock, and the planes it missed are a counted gap: the sink's summary
/// adds up (received + missing = expected) and the run finishes.
#[test]
fn a_restarted_source_resumes_and_its_gap_is_counted() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let out = tempfile::tempdir().expect("tempdir");
    let mut g: serde_yaml::Value =
        serde_yaml::from_str(&std::fs::read_to_string(graph("spike-tfp-live.yml")).expect("graph"))
            .expect("yaml");
    for node in g["nodes"].as_sequence_mut().expect("nodes") {
        if node["id"].as_str() == Some("spike-source") {
            let map = node.as_mapping_mut().expect("node");
            map.insert("restart_policy".into(), "on-failure".into());
            map.insert("max_restarts".into(), 2.into());
            map.insert("restart_delay".into(), 0.1.into());
        }
    }
    let frames = out.path().join("frames");
    let path = neuspike::graph::write_built_in(
        &serde_yaml::to_string(&g).expect("yaml"),
        out.path(),
        "a_restarted_source_resumes_and_its_gap_is_counted",
        |id, _| match id {
            // 6 s of a 5 kHz camera (what a machine without AVX-512 simulates in real time
            // with a core to spare), a frame every 25 planes.
            "spike-source" => Some(
                "--scene bright-static --rate-hz 5000 --chunk-planes 25 --max-planes 30000 --seed 1 --pace realtime"
                    .into(),
            ),
            "align" => Some("--window-planes 33 --stride-planes 25".into()),
            "sink" => Some(format!("--out {} --bit-depth 8 --write-every 10", frames.display())),
            _ => None,
        },
    )
    .expect("graph written");
    let run = std::thread::spawn(move || {
        neuspike::graph::run(&path, &[], false, Some(Duration::from_secs(120)), None)
    });
    let csv = frames.join("metrics.csv");
    let start = Instant::now();
    while rows(&csv) < 200 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no frames after 60 s"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let pid = child_named("neuspike-spike-source").expect("the source is running");
    let status = std::process::Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    let report = run
        .join()
        .expect("run thread")
        .expect("the runner returned");
    let text = std::fs::read_to_string(frames.join("summary.yml")).expect("summary.yml");
    let summary: neuspike_sink::report::SummaryFile = serde_yaml::from_str(&text).expect("yaml");
    let tfp = &summary.inputs["tfp"].counts;
    // Windows at planes 25, 50, ..., 29,975 (plane 0's would start before the first plane).
    assert_eq!(tfp.expected, 1199, "{text}");
    assert!(tfp.ended, "{text}");
    assert!(tfp.missing > 0, "the restart lost no frame? {text}");
    assert_eq!(tfp.received + tfp.missing, tfp.expected, "{text}");
    // The source came back before the camera's 6 s were over: most frames arrived.
    assert!(tfp.received > 600, "{text}");
    // The frames after the restart are on time again: the gap was not waited for.
    let latency = summary.inputs["tfp"].latency.expect("latency");
    assert!(latency.p50_ms < 100.0, "{text}");
    eprintln!("failures after the restart: {:?}; {text}", report.failures);
}
