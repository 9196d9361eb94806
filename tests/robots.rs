//! neuspike as a robot's peers see it, checked by programs that share no code with it: Python
//! with eclipse-zenoh, rosbags (ROS 2's message definitions and CDR) and pyarrow.
//!
//! Each test skips with a printed notice where Python lacks a package; CI installs them.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether `python3` imports every module of `modules`; prints why not.
fn python_has(modules: &str) -> bool {
    let ok = Command::new("python3")
        .args(["-c", &format!("import {modules}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        eprintln!(
            "notice: skipped: python3 cannot import {modules} \
             (pip install eclipse-zenoh==1.10.2 rosbags pyarrow numpy)"
        );
    }
    ok
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// Starts a Python peer and waits for its `ready` line.
fn start_peer(script: &str, args: &[String]) -> Child {
    let mut child = Command::new("python3")
        .arg(root().join(script))
        .args(args)
        .stdout(Stdio::piped())
        .spawn()
        .expect("python3 starts");
    let stdout = child.stdout.take().expect("stdout");
    let mut lines = BufReader::new(stdout).lines();
    match lines.next() {
        Some(Ok(l)) if l.trim() == "ready" => {}
        other => {
            let _ = child.kill();
            panic!("{script} did not get ready: {other:?}");
        }
    }
    // The rest of its output goes on to this test's output.
    std::thread::spawn(move || {
        for l in lines.map_while(Result::ok) {
            eprintln!("{l}");
        }
    });
    child
}

fn wait(mut child: Child, limit: Duration) {
    let start = std::time::Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            assert!(status.success(), "the Python peer failed: {status}");
            return;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("the Python peer did not finish in {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn read_png8(path: &Path) -> Vec<u8> {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .into_luma8()
        .into_raw()
}

/// `graphs/publish.yml`, one second of a 20 kHz camera at 200 frames/s, heard by an independent
/// ROS 2 subscriber: every frame arrives as a `sensor_msgs/msg/Image` (mono8) with its
/// attachment, numbered 1, 2, 3, ... without a gap, stamped with the frame's instant, and its
/// pixels are exactly those of the PNG the sink wrote for the same frame.
#[test]
fn an_independent_ros2_subscriber_sees_every_frame_with_the_sinks_pixels() {
    if !python_has("zenoh, rosbags, pyarrow, numpy") {
        return;
    }
    let out = tempfile::tempdir().expect("tempdir");
    let heard = out.path().join("heard");
    let port = free_port();
    let peer = start_peer(
        "tests/robots/ros2_image_subscriber.py",
        &[
            "--listen".into(),
            format!("tcp/127.0.0.1:{port}"),
            "--out".into(),
            heard.display().to_string(),
        ],
    );
    let sink_out = out.path().join("sink");
    let report = neuspike::graph::run(
        &root().join("graphs/publish.yml"),
        &[
            ("spike-source".into(), "--max-planes 20000".into()),
            (
                "sink".into(),
                format!("--out {} --write-every 1", sink_out.display()),
            ),
            ("publish".into(), format!("--connect tcp/127.0.0.1:{port}")),
        ],
        true,
        Some(Duration::from_secs(300)),
        None,
    )
    .expect("graph ran");
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    wait(peer, Duration::from_secs(60));

    let report = std::fs::read_to_string(heard.join("report.json")).expect("report");
    assert!(report.contains("\"problems\": []"), "{report}");
    assert!(report.contains("\"publishers\": 1"), "{report}");

    // The sink's frames, in sequence order, with their instants.
    let csv = std::fs::read_to_string(sink_out.join("metrics.csv")).expect("metrics");
    let mut frames: Vec<(u64, i64, String)> = csv
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            (
                v[0].parse().expect("seq"),
                v[1].parse().expect("t_ref_ns"),
                v[v.len() - 1].to_string(),
            )
        })
        .collect();
    frames.sort();
    assert!(frames.len() > 150, "{} frames", frames.len());
    assert!(
        report.contains(&format!("\"images\": {}", frames.len())),
        "{report}"
    );
    assert!(
        report.contains(&format!("\"arrow_eos_count\": {}", frames.len())),
        "{report}"
    );

    let read = |name: &str| std::fs::read(heard.join(name)).expect("the peer's arrays");
    let pixels = read("images.bin");
    let int64 = |bytes: Vec<u8>| -> Vec<i64> {
        bytes
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect()
    };
    let stamps = int64(read("stamps.bin"));
    let seqs = int64(read("seqs.bin"));
    let expected_seqs: Vec<i64> = (1..=frames.len() as i64).collect();
    assert_eq!(seqs, expected_seqs, "attachment sequence numbers");
    let size = pixels.len() / frames.len();
    for (i, (_, t_ref_ns, file)) in frames.iter().enumerate() {
        assert_eq!(stamps[i], *t_ref_ns, "image {i}: header.stamp");
        let png = read_png8(&sink_out.join(file));
        assert_eq!(png.len(), size, "image {i}: size");
        assert!(
            png == pixels[i * size..(i + 1) * size],
            "image {i}: pixels differ from {file}"
        );
    }
}
