//! `graphs/distributed.yml` on two machines: the camera side and the compute side each behind a
//! dora daemon in a network namespace of its own, joined by a veth pair shaped as a 1 Gbit/s link
//! with 0.5 ms of delay. Ten seconds of a 20 kHz camera at 200 frames/s cross it without a loss,
//! and the frames are byte for byte those of the same graph on one machine.
//!
//! Making namespaces needs root and `ip`; where they cannot be made, the test says so and passes.

use std::path::{Path, PathBuf};
use std::process::Command;

use neuspike::cluster::{Cluster, Machine};
use neuspike_sink::report::SummaryFile;

fn graph() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("graphs/distributed.yml")
}

/// `ip ARGS`, true when it succeeded.
fn ip(args: &[&str]) -> bool {
    Command::new("ip")
        .args(args)
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Two network namespaces joined by a veth pair: `camera` at .1, `compute` at .2. Removed (with
/// whatever still runs in them) when dropped.
struct TwoHosts {
    camera: String,
    compute: String,
    compute_addr: String,
    /// What the link is shaped as, for the log.
    link: String,
}

impl TwoHosts {
    /// Makes them, or says why it cannot.
    fn make() -> Result<Self, String> {
        let id = std::process::id();
        let subnet = format!("10.213.{}", id % 250);
        let hosts = TwoHosts {
            camera: format!("neuspike-cam-{id}"),
            compute: format!("neuspike-cmp-{id}"),
            compute_addr: format!("{subnet}.2"),
            link: String::new(),
        };
        if !ip(&["netns", "add", &hosts.camera]) || !ip(&["netns", "add", &hosts.compute]) {
            return Err("`ip netns add` failed (root and iproute2 are needed)".into());
        }
        let (veth_cam, veth_cmp) = (format!("nsc{id}"), format!("nsp{id}"));
        let steps: Vec<Vec<String>> = vec![
            vec![
                "link", "add", &veth_cam, "type", "veth", "peer", "name", &veth_cmp,
            ],
            vec!["link", "set", &veth_cam, "netns", &hosts.camera],
            vec!["link", "set", &veth_cmp, "netns", &hosts.compute],
        ]
        .into_iter()
        .map(|v| v.into_iter().map(str::to_string).collect())
        .collect();
        for step in &steps {
            let args: Vec<&str> = step.iter().map(String::as_str).collect();
            if !ip(&args) {
                return Err(format!("`ip {}` failed", args.join(" ")));
            }
        }
        let mut hosts = hosts;
        let mut shaped = Vec::new();
        for (ns, dev, addr) in [
            (&hosts.camera, &veth_cam, format!("{subnet}.1/24")),
            (&hosts.compute, &veth_cmp, format!("{subnet}.2/24")),
        ] {
            let ok = ip(&["-n", ns, "addr", "add", &addr, "dev", dev])
                && ip(&["-n", ns, "link", "set", "lo", "up"])
                && ip(&["-n", ns, "link", "set", dev, "up"]);
            if !ok {
                return Err(format!("cannot bring up {dev} in {ns}"));
            }
            shaped.push(shape(ns, dev)?);
        }
        hosts.link = shaped.join("; ");
        Ok(hosts)
    }

    fn wrap(ns: &str) -> Vec<String> {
        ["ip", "netns", "exec", ns].map(str::to_string).to_vec()
    }
}

/// Shapes `dev`'s egress as a 1 Gbit/s link with 0.5 ms of delay (netem). A kernel without netem
/// gets the rate alone (tbf), said in the returned description.
fn shape(ns: &str, dev: &str) -> Result<String, String> {
    let tc = |args: &[&str]| {
        Command::new("ip")
            .args([
                "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev, "root",
            ])
            .args(args)
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if tc(&["netem", "delay", "0.5ms", "rate", "1gbit"]) {
        return Ok(format!("{dev}: netem 1 Gbit/s, 0.5 ms"));
    }
    if tc(&["tbf", "rate", "1gbit", "burst", "128kb", "latency", "5ms"]) {
        return Ok(format!(
            "{dev}: tbf 1 Gbit/s (this kernel has no netem: no added delay)"
        ));
    }
    Err(format!("tc cannot shape {dev} in {ns}"))
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        for ns in [&self.camera, &self.compute] {
            if let Ok(o) = Command::new("ip").args(["netns", "pids", ns]).output() {
                for pid in String::from_utf8_lossy(&o.stdout).split_whitespace() {
                    let _ = Command::new("kill").args(["-9", pid]).status();
                }
            }
            ip(&["netns", "del", ns]);
        }
    }
}

fn summary(out: &Path) -> SummaryFile {
    let text = std::fs::read_to_string(out.join("summary.yml")).expect("summary.yml");
    serde_yaml::from_str(&text).expect("summary.yml parses")
}

fn pngs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("frames folder")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    v.sort();
    v
}

#[test]
fn the_distributed_graph_crosses_a_network_link_without_loss_and_as_on_one_machine() {
    let hosts = match TwoHosts::make() {
        Ok(h) => h,
        Err(why) => {
            eprintln!("SKIPPED: network namespaces cannot be made here: {why}");
            return;
        }
    };
    if Command::new("dora").arg("--version").output().is_err() {
        eprintln!(
            "SKIPPED: the dora CLI is not installed (`pip install dora-rs-cli==1.1.0`): the cluster cannot start"
        );
        return;
    }
    eprintln!("link: {}", hosts.link);
    let tmp = tempfile::tempdir().expect("tmp");
    let out = |name: &str| tmp.path().join(name);
    let sink = |dir: &Path| vec![("sink".to_string(), format!("--out {}", dir.display()))];

    let one = neuspike::graph::run(&graph(), &sink(&out("one")), true, None, None)
        .expect("one machine ran");
    assert!(one.failures.is_empty(), "{:?}", one.failures);

    let cluster = Cluster::Start {
        coordinator: hosts.compute_addr.parse().expect("address"),
        port: Some(6013),
        wrap: TwoHosts::wrap(&hosts.compute),
        machines: vec![
            Machine {
                id: "camera".into(),
                wrap: TwoHosts::wrap(&hosts.camera),
            },
            Machine {
                id: "compute".into(),
                wrap: TwoHosts::wrap(&hosts.compute),
            },
        ],
    };
    let two = neuspike::cluster::run(&graph(), &sink(&out("two")), false, &cluster)
        .expect("two machines ran");
    assert!(
        two.failures.is_empty(),
        "{:?} logs {:?}",
        two.failures,
        two.logs
    );

    // 200,000 planes, a 33-plane window every 100: 1,999 frames, all of them there.
    for run in ["one", "two"] {
        let s = summary(&out(run));
        let tfp = &s.inputs["tfp"];
        assert_eq!(
            (tfp.counts.expected, tfp.counts.received, tfp.counts.missing),
            (1999, 1999, 0),
            "{run}: {tfp:?}"
        );
        assert!(tfp.counts.ended, "{run}: {tfp:?}");
    }
    let (a, b) = (pngs(&out("one").join("tfp")), pngs(&out("two").join("tfp")));
    assert_eq!(a.len(), 1999);
    let names = |v: &[PathBuf]| -> Vec<_> {
        v.iter()
            .map(|p| p.file_name().map(|n| n.to_owned()))
            .collect()
    };
    assert_eq!(names(&a), names(&b));
    for (x, y) in a.iter().zip(&b) {
        let (x_bytes, y_bytes) = (
            std::fs::read(x).expect("png"),
            std::fs::read(y).expect("png"),
        );
        assert!(
            x_bytes == y_bytes,
            "{} differs from {}",
            y.display(),
            x.display()
        );
    }
    let lat = two
        .out_dirs
        .first()
        .and_then(|d| summary(d).inputs["tfp"].latency);
    eprintln!(
        "two machines: {:.2} s, latency {lat:?}",
        two.elapsed.as_secs_f64()
    );
}
