//! neuspike as a robot's peers see it, checked by programs that share no code with it: Python
//! with eclipse-zenoh, rosbags (ROS 2's message definitions and CDR) and pyarrow.
//!
//! Each test skips with a printed notice where Python lacks a package; CI installs them.

mod common;
use common::{python_has, root, run_graph};

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

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
/// pixels are exactly those of the PNG the sink wrote for the same frame. The publish node records
/// the run as a ROS 2 bag (MCAP) too, and the MCAP library reads the same images back from it.
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
    run_graph(
        "graphs/publish.yml",
        &[
            ("spike-source", "--max-planes 20000".into()),
            (
                "sink",
                format!("--out {} --write-every 1", sink_out.display()),
            ),
            (
                "publish",
                format!(
                    "--connect tcp/127.0.0.1:{port} --mcap {}",
                    out.path().join("run.mcap").display()
                ),
            ),
        ],
    );
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

    check_images(&heard, &frames, &sink_out, true);

    // The same run, recorded as a ROS 2 bag by the publish node, read by the MCAP library.
    if python_has("mcap") {
        let bag = out.path().join("bag");
        let read = Command::new("python3")
            .arg(root().join("tests/robots/read_bag.py"))
            .arg(out.path().join("run.mcap"))
            .arg("--out")
            .arg(&bag)
            .output()
            .expect("python3 runs");
        assert!(
            read.status.success(),
            "the bag is not a ROS 2 bag of the frames: {}{}",
            String::from_utf8_lossy(&read.stdout),
            String::from_utf8_lossy(&read.stderr)
        );
        let report = std::fs::read_to_string(bag.join("report.json")).expect("report");
        assert!(
            report.contains(&format!("\"arrow_messages\": {}", frames.len() + 1)),
            "every neuspike message and the end-of-stream marker: {report}"
        );
        check_images(&bag, &frames, &sink_out, false);
    }
}

/// The images a peer wrote into `dir` (`images.bin`, `stamps.bin`, and with `numbered`
/// `seqs.bin`) against the sink's frames `(seq, t_ref_ns, file)`: the same count and order,
/// stamps equal to the frames' instants, pixels equal to the PNGs'.
fn check_images(dir: &Path, frames: &[(u64, i64, String)], sink_out: &Path, numbered: bool) {
    let read = |name: &str| std::fs::read(dir.join(name)).expect("the peer's arrays");
    let pixels = read("images.bin");
    let int64 = |bytes: Vec<u8>| -> Vec<i64> {
        bytes
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect()
    };
    let stamps = int64(read("stamps.bin"));
    assert_eq!(stamps.len(), frames.len(), "{}", dir.display());
    if numbered {
        let seqs = int64(read("seqs.bin"));
        let expected_seqs: Vec<i64> = (1..=frames.len() as i64).collect();
        assert_eq!(seqs, expected_seqs, "attachment sequence numbers");
    }
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

/// An independent ROS 2 event-camera driver (Python: rosbags' CDR, EVT 3.0 words made there,
/// rmw_zenoh's attachment) feeds `graphs/ros2-events.yml`: the event source takes its 100
/// packets over zenoh and the publish node hands the batches back as neuspike's EventBatches,
/// which the driver's side checks event for event (time, place, polarity), in order, with the
/// end-of-stream count.
#[test]
fn an_independent_ros2_event_driver_feeds_the_event_source_event_for_event() {
    if !python_has("zenoh, rosbags, pyarrow, numpy") {
        return;
    }
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let peer = start_peer(
        "tests/robots/ros2_event_publisher.py",
        &["--listen".into(), endpoint.clone()],
    );
    run_graph(
        "graphs/ros2-events.yml",
        &[
            (
                "event-source",
                format!("--connect {endpoint} --silence-s 2"),
            ),
            ("publish", format!("--connect {endpoint}")),
        ],
    );
    // The peer exits 0 only when every event matched.
    wait(peer, Duration::from_secs(60));
}

/// `neuspike publish-file` on one side, `graphs/remote.yml` on the other: a simulated 10,000-plane
/// recording crosses zenoh as SpikeChunks, as fast as the graph takes them, and the graph's frames
/// are all there (none missing) and byte-identical to those of the same recording played from
/// the file (`graphs/reconstruct-dat.yml`).
#[test]
fn a_recording_sent_over_zenoh_reconstructs_as_from_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join("rec");
    let status = Command::new(env!("CARGO_BIN_EXE_neuspike"))
        .args([
            "simulate",
            "bright-fast",
            "--planes",
            "10000",
            "--no-events",
            "--gt-every-planes",
            "0",
            "--out",
        ])
        .arg(&rec)
        .status()
        .expect("neuspike simulate");
    assert!(status.success());
    let dat = rec.join("spikes.dat");
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let config = dir.path().join("zenoh.json5");
    std::fs::write(
        &config,
        format!(
            "{{ mode: \"peer\", listen: {{ endpoints: [\"{endpoint}\"] }}, scouting: {{ multicast: {{ enabled: false }} }} }}"
        ),
    )
    .expect("config");

    let remote_out = dir.path().join("remote");
    let graph = {
        let remote_out = remote_out.clone();
        let config = config.clone();
        std::thread::spawn(move || {
            run_graph(
                "graphs/remote.yml",
                &[
                    (
                        "spike-source",
                        format!("--zenoh-config {}", config.display()),
                    ),
                    ("sink", format!("--out {}", remote_out.display())),
                ],
            )
        })
    };
    let published = neuspike::publish_file::run(&neuspike::publish_file::PublishFile {
        file: dat.clone(),
        key: None,
        args: String::new(),
        pace: neuspike_runtime::Pace::Fast,
        wait_s: 120,
        zenoh: neuspike_net::ZenohArgs {
            listen: vec![],
            connect: vec![endpoint],
            ..Default::default()
        },
    })
    .expect("published");
    assert_eq!((published.messages, published.items), (500, 10_000));
    graph.join().expect("the remote graph ran");

    let local_out = dir.path().join("local");
    run_graph(
        "graphs/reconstruct-dat.yml",
        &[
            ("spike-source", format!("--file {}", dat.display())),
            ("sink", format!("--out {}", local_out.display())),
        ],
    );

    let summary = std::fs::read_to_string(remote_out.join("summary.md")).expect("summary");
    let row = summary
        .lines()
        .find(|l| l.starts_with("| tfp |") && l.ends_with("| yes |"))
        .unwrap_or_else(|| panic!("{summary}"));
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    assert_eq!(cells[2], cells[3], "expected = received: {row}");
    assert_eq!(cells[5], "0", "missing: {row}");
    let frames = |d: &Path| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(d.join("tfp"))
            .expect("frames")
            .map(|e| e.expect("entry").path())
            .collect();
        v.sort();
        v
    };
    let (a, b) = (frames(&remote_out), frames(&local_out));
    assert!(a.len() > 900, "{} frames", a.len());
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.file_name(), y.file_name());
        assert!(
            std::fs::read(x).expect("png") == std::fs::read(y).expect("png"),
            "{} differs",
            x.display()
        );
    }
}
