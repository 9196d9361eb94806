//! Running a graph whose nodes name machines (`deploy: { machine: ... }`) on a dora cluster: one
//! coordinator and one daemon per machine, started here on loopback for a try-out, or a cluster
//! already running on real machines.
//!
//! The graph is resolved first (node binaries, working folders, credits), written with the
//! message types into a folder of its own, and started with the stock dora CLI (`dora start
//! --attach`, from `pip install dora-rs-cli==1.1.0`), the program dora ships for clusters.

use std::collections::BTreeSet;
use std::io::{BufRead, BufReader};
use std::net::{IpAddr, Ipv4Addr, TcpListener};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use eyre::{WrapErr, bail, eyre};
use serde_yaml::Value;

use crate::graph::{self, Report};

/// The dora CLI's program name.
const DORA: &str = "dora";

/// The dora release the nodes are built against: the CLI must speak its protocol.
const DORA_VERSION: &str = "1.1.";

/// How long the daemons get to register with the coordinator.
const REGISTER_TIMEOUT: Duration = Duration::from_secs(30);

/// One machine of a cluster started here: its daemon runs behind `wrap` (a command prefix such
/// as `ip netns exec camera`; empty runs it directly).
#[derive(Clone, Debug, Default)]
pub struct Machine {
    /// The `deploy.machine` id the graph's nodes name.
    pub id: String,
    /// Command prefix the daemon runs under.
    pub wrap: Vec<String>,
}

/// Where the graph runs.
#[derive(Clone, Debug)]
pub enum Cluster {
    /// Start a coordinator and one daemon per machine the graph names, run the graph, stop them.
    Start {
        /// Address the coordinator binds and the daemons dial.
        coordinator: IpAddr,
        /// Its port; `None` picks a free one on loopback.
        port: Option<u16>,
        /// Command prefix for the coordinator and `dora start` (empty: run directly).
        wrap: Vec<String>,
        /// Per-machine settings; a machine the graph names and this list does not gets a daemon
        /// run directly.
        machines: Vec<Machine>,
    },
    /// A coordinator already running, with its daemons registered.
    Existing {
        /// The coordinator's address.
        coordinator: IpAddr,
        /// Its port.
        port: u16,
    },
}

impl Cluster {
    /// A try-out cluster on this machine: coordinator and daemons on loopback.
    pub fn loopback() -> Self {
        Cluster::Start {
            coordinator: IpAddr::V4(Ipv4Addr::LOCALHOST),
            port: None,
            wrap: Vec::new(),
            machines: Vec::new(),
        }
    }
}

/// The machines a graph's nodes name under `deploy.machine`, sorted; empty for a graph that names
/// none. A graph that places some nodes and not others is an error naming the first unplaced one.
pub fn machines(graph: &Value, path: &Path) -> eyre::Result<Vec<String>> {
    let mut named = BTreeSet::new();
    let mut unplaced = None;
    for node in graph
        .get("nodes")
        .and_then(Value::as_sequence)
        .into_iter()
        .flatten()
    {
        match node
            .get("deploy")
            .and_then(|d| d.get("machine"))
            .and_then(Value::as_str)
        {
            Some(m) => {
                named.insert(m.to_string());
            }
            None => {
                unplaced.get_or_insert_with(|| {
                    node.get("id")
                        .and_then(Value::as_str)
                        .unwrap_or("?")
                        .to_string()
                });
            }
        }
    }
    if let (false, Some(id)) = (named.is_empty(), unplaced) {
        bail!(
            "{}: node `{id}` has no deploy.machine while others do: place every node or none",
            path.display()
        );
    }
    Ok(named.into_iter().collect())
}

/// Whether the graph file at `path` places its nodes on machines.
///
/// # Errors
/// The file cannot be read or parsed, or places some nodes and not others.
pub fn places_nodes(path: &Path) -> eyre::Result<bool> {
    let g = neuspike_pipeline::read_graph(path)?;
    Ok(!machines(&g, path)?.is_empty())
}

/// Gives every placed node the graph's own folder as its working folder when it names none, so
/// that relative paths (`--out ../out/x`) mean on every machine what they mean beside the graph.
fn set_working_dirs(graph: &mut Value, graph_dir: &Path) {
    let list = graph.get_mut("nodes").and_then(Value::as_sequence_mut);
    for node in list.into_iter().flatten() {
        let Some(deploy) = node.get_mut("deploy").and_then(Value::as_mapping_mut) else {
            continue;
        };
        if !deploy.contains_key("working_dir") {
            deploy.insert("working_dir".into(), graph_dir.display().to_string().into());
        }
    }
}

/// Checks that the dora CLI is on `PATH` at the nodes' release.
fn check_dora_cli() -> eyre::Result<()> {
    let out = Command::new(DORA).arg("--version").output();
    let out = match out {
        Ok(o) => o,
        Err(_) => bail!(
            "a graph placed on machines runs on a dora cluster, and the dora CLI is not on PATH: install it with `pip install dora-rs-cli==1.1.0`"
        ),
    };
    let version = String::from_utf8_lossy(&out.stdout);
    let version = version.trim();
    if !version
        .rsplit(' ')
        .next()
        .unwrap_or("")
        .starts_with(DORA_VERSION)
    {
        bail!(
            "the dora CLI on PATH is `{version}`, the nodes speak dora {DORA_VERSION}x: install it with `pip install dora-rs-cli==1.1.0`"
        );
    }
    Ok(())
}

/// A free TCP port on loopback (the OS picks it; a race with another program taking it in the
/// meantime shows as that process failing to bind).
fn free_port() -> eyre::Result<u16> {
    let l = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).wrap_err("cannot find a free port")?;
    Ok(l.local_addr().wrap_err("cannot find a free port")?.port())
}

/// The dora CLI behind the command prefix `wrap` (`ip netns exec ns dora`; plain `dora` when
/// empty).
fn dora(wrap: &[String]) -> Command {
    let mut words = wrap.iter().map(String::as_str).chain([DORA]);
    let mut command = Command::new(words.next().unwrap_or(DORA));
    command.args(words);
    command
}

/// The processes of a cluster started here; killed when dropped.
struct Processes {
    children: Vec<(String, Child, PathBuf)>,
}

impl Processes {
    /// Starts `wrap + dora args` in `dir`, its output into `dir/<name>.log`.
    fn spawn(
        &mut self,
        name: &str,
        wrap: &[String],
        args: &[String],
        dir: &Path,
    ) -> eyre::Result<()> {
        let log = dir.join(format!("{name}.log"));
        let file = std::fs::File::create(&log)
            .wrap_err_with(|| format!("cannot create {}", log.display()))?;
        let err = file
            .try_clone()
            .wrap_err_with(|| format!("cannot create {}", log.display()))?;
        let child = dora(wrap)
            .args(args)
            .current_dir(dir)
            .stdin(Stdio::null())
            .stdout(file)
            .stderr(err)
            .spawn()
            .wrap_err_with(|| format!("cannot start the dora {name}"))?;
        self.children.push((name.to_string(), child, log));
        Ok(())
    }

    /// An error naming the first process that has exited, with the end of its log.
    fn check_alive(&mut self) -> eyre::Result<()> {
        for (name, child, log) in &mut self.children {
            if let Ok(Some(status)) = child.try_wait() {
                let text = std::fs::read_to_string(&*log).unwrap_or_default();
                let tail: Vec<&str> = text.lines().rev().take(5).collect();
                let tail: Vec<&str> = tail.into_iter().rev().collect();
                bail!(
                    "the dora {name} exited ({status}) before the graph ran; its log {}:\n{}",
                    log.display(),
                    tail.join("\n")
                );
            }
        }
        Ok(())
    }
}

impl Drop for Processes {
    fn drop(&mut self) {
        for (_, child, _) in &mut self.children {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// `--coordinator-addr A --coordinator-port P`.
fn coordinator_args(addr: IpAddr, port: u16) -> Vec<String> {
    vec![
        "--coordinator-addr".into(),
        addr.to_string(),
        "--coordinator-port".into(),
        port.to_string(),
    ]
}

/// Waits until a daemon of every machine in `ids` has registered with the coordinator.
fn wait_for_daemons(
    procs: &mut Processes,
    wrap: &[String],
    addr: IpAddr,
    port: u16,
    ids: &[String],
) -> eyre::Result<()> {
    let start = Instant::now();
    loop {
        procs.check_alive()?;
        let out = dora(wrap)
            .args(["cluster", "status"])
            .args(coordinator_args(addr, port))
            .stdin(Stdio::null())
            .output();
        if let Ok(out) = out {
            let text = String::from_utf8_lossy(&out.stdout);
            let registered = |id: &String| text.lines().any(|l| l.starts_with(&format!("{id}-")));
            if out.status.success() && ids.iter().all(registered) {
                return Ok(());
            }
        }
        if start.elapsed() > REGISTER_TIMEOUT {
            bail!(
                "the daemons of {} did not register with the coordinator at {addr}:{port} within {} s",
                ids.join(", "),
                REGISTER_TIMEOUT.as_secs()
            );
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Runs `dora start --attach` and relays its lines: nodes' log lines as `node | message`, errors
/// and warnings as they are, the CLI's stack traces not at all. Returns whether it succeeded and
/// the failures it reported, as (node, cause).
fn start_and_attach(
    wrap: &[String],
    graph_path: &Path,
    addr: IpAddr,
    port: u16,
    dir: &Path,
) -> eyre::Result<(bool, Vec<(String, String)>)> {
    let mut child = dora(wrap)
        .arg("start")
        .arg(graph_path)
        .arg("--attach")
        .args(coordinator_args(addr, port))
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .wrap_err("cannot start `dora start`")?;
    let stderr = child.stderr.take();
    let relay_err = std::thread::spawn(move || stderr.map(relay).unwrap_or_default());
    let mut failures = child.stdout.take().map(relay).unwrap_or_default();
    failures.extend(relay_err.join().unwrap_or_default());
    let status = child.wait().wrap_err("`dora start` did not finish")?;
    failures.sort();
    failures.dedup();
    Ok((status.success(), failures))
}

/// Relays the lines of `dora start --attach` (see [`start_and_attach`]); returns the nodes it
/// reported as failed.
fn relay(stream: impl std::io::Read) -> Vec<(String, String)> {
    let mut failures = Vec::new();
    let mut in_trace = false;
    for line in BufReader::new(stream).lines().map_while(Result::ok) {
        if line.starts_with("Stack backtrace:") || line.starts_with("Location:") {
            in_trace = true;
        }
        if in_trace || line.trim().is_empty() || line.starts_with("----") {
            continue;
        }
        if let Some(rest) = line.strip_prefix("Node `")
            && let Some((node, cause)) = rest.split_once("` failed: ")
        {
            failures.push((node.to_string(), cause.trim().to_string()));
            continue;
        }
        match node_line(&line) {
            Some((node, message)) => eprintln!("{node:>14} | {message}"),
            None if line.contains(" INFO ") => {}
            None => eprintln!("{:>14} | {}", "dora", line.trim_end()),
        }
    }
    failures
}

/// `HH:MM:SS stdout <node> on daemon `<machine>`: <message>` as (node, message).
fn node_line(line: &str) -> Option<(&str, &str)> {
    let rest = line.get(9..)?.strip_prefix("stdout ")?;
    let (node, rest) = rest.split_once(" on daemon `")?;
    let (_, message) = rest.split_once("`: ")?;
    Some((node, message.trim()))
}

/// Runs a graph whose nodes name machines on `cluster`: builds the nodes (when `build_first`),
/// resolves the graph into a folder of its own and starts it. The cluster's and the run's logs are
/// kept, and named in the report, when the run fails.
///
/// # Errors
/// The graph cannot be read or resolved, the dora CLI is missing, or the cluster does not start.
/// A node that fails is not an error here: it is in the report.
pub fn run(
    graph_path: &Path,
    overrides: &[(String, String)],
    build_first: bool,
    cluster: &Cluster,
) -> eyre::Result<Report> {
    let graph_path = graph_path
        .canonicalize()
        .wrap_err_with(|| format!("graph {} not found", graph_path.display()))?;
    let graph_dir = graph_path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut g = graph::prepare(&graph_path, overrides, build_first)?;
    let ids = machines(&g, &graph_path)?;
    if ids.is_empty() {
        bail!(
            "{}: no node names a machine (deploy.machine): run it with `neuspike run` alone",
            graph_path.display()
        );
    }
    set_working_dirs(&mut g, &graph_dir);
    check_dora_cli()?;
    let out_dirs = graph::sink_out_dirs(&graph_path, &g);

    let work = tempfile::Builder::new()
        .prefix("neuspike-cluster-")
        .tempdir()
        .wrap_err("cannot create a folder for the cluster")?;
    let dir = work.path().to_path_buf();
    graph::write_types(&dir)?;
    let resolved = dir.join("graph.yml");
    let body = serde_yaml::to_string(&g).wrap_err("cannot write the resolved graph")?;
    std::fs::write(&resolved, body)
        .wrap_err_with(|| format!("cannot write {}", resolved.display()))?;
    let overlay = dir.join("zenoh.json5");
    std::fs::write(&overlay, neuspike_runtime::ZENOH_OVERLAY)
        .wrap_err_with(|| format!("cannot write {}", overlay.display()))?;

    let mut procs = Processes {
        children: Vec::new(),
    };
    let (addr, port, wrap) = match cluster {
        Cluster::Existing { coordinator, port } => (*coordinator, *port, Vec::new()),
        Cluster::Start {
            coordinator,
            port,
            wrap,
            machines,
        } => {
            let port = match port {
                Some(p) => *p,
                None => free_port()?,
            };
            procs.spawn(
                "coordinator",
                wrap,
                &[
                    "coordinator".into(),
                    "--interface".into(),
                    coordinator.to_string(),
                    "--port".into(),
                    port.to_string(),
                    "--store".into(),
                    "memory".into(),
                ],
                &dir,
            )?;
            for id in &ids {
                let machine = machines.iter().find(|m| &m.id == id);
                let machine_wrap = machine.map(|m| m.wrap.clone()).unwrap_or_default();
                let mut args: Vec<String> = vec![
                    "daemon".into(),
                    "--machine-id".into(),
                    id.clone(),
                    "-c".into(),
                    coordinator.to_string(),
                    "--coordinator-port".into(),
                    port.to_string(),
                    "--zenoh-no-multicast".into(),
                    "--zenoh-config-overlay".into(),
                    overlay.display().to_string(),
                ];
                // Daemons sharing a host need their own local ports.
                if machine_wrap.is_empty() {
                    args.extend(["--local-listen-port".into(), free_port()?.to_string()]);
                }
                procs.spawn(&format!("daemon-{id}"), &machine_wrap, &args, &dir)?;
            }
            wait_for_daemons(&mut procs, wrap, *coordinator, port, &ids)?;
            (*coordinator, port, wrap.clone())
        }
    };
    tracing::info!(
        "graph {} on machines {} (coordinator {addr}:{port})",
        graph_path.display(),
        ids.join(", ")
    );
    let started_at = std::time::SystemTime::now();
    let started = Instant::now();
    let (ok, mut failures) = start_and_attach(&wrap, &resolved, addr, port, &dir)?;
    let elapsed = started.elapsed();
    drop(procs);
    if !ok && failures.is_empty() {
        failures.push((
            "dora".to_string(),
            "`dora start` failed without naming a node (see the logs)".to_string(),
        ));
    }
    let logs = if failures.is_empty() {
        None
    } else {
        Some(work.keep())
    };
    Ok(Report {
        failures,
        out_dirs,
        elapsed,
        started_at,
        logs,
    })
}

/// Parses `ADDR[:PORT]` (port 6013, dora's, when left out).
pub fn parse_coordinator(s: &str) -> eyre::Result<Cluster> {
    let (addr, port) = match s.rsplit_once(':') {
        Some((a, p)) if !a.contains(':') || a.starts_with('[') => (
            a.trim_matches(['[', ']']),
            p.parse::<u16>()
                .map_err(|_| eyre!("--coordinator `{s}`: the port `{p}` is not a number"))?,
        ),
        _ => (s, 6013),
    };
    let coordinator: IpAddr = addr
        .parse()
        .map_err(|_| eyre!("--coordinator `{s}`: `{addr}` is not an IP address"))?;
    Ok(Cluster::Existing { coordinator, port })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn machines_are_the_ones_the_nodes_name_and_all_nodes_must_name_one() {
        let g: Value = serde_yaml::from_str(
            "nodes:\n  - id: a\n    deploy: { machine: camera }\n  - id: b\n    deploy: { machine: compute }\n  - id: c\n    deploy: { machine: camera }\n",
        )
        .expect("yaml");
        assert_eq!(
            machines(&g, Path::new("g.yml")).expect("placed"),
            ["camera", "compute"]
        );
        let none: Value = serde_yaml::from_str("nodes:\n  - id: a\n").expect("yaml");
        assert!(
            machines(&none, Path::new("g.yml"))
                .expect("none")
                .is_empty()
        );
        let half: Value = serde_yaml::from_str(
            "nodes:\n  - id: a\n    deploy: { machine: camera }\n  - id: sink\n",
        )
        .expect("yaml");
        let e = machines(&half, Path::new("g.yml"))
            .expect_err("half placed")
            .to_string();
        assert!(e.contains("g.yml") && e.contains("`sink`"), "{e}");
    }

    #[test]
    fn working_dirs_default_to_the_graphs_folder_and_deploy_can_be_stripped() {
        let mut g: Value = serde_yaml::from_str(
            "nodes:\n  - id: a\n    deploy: { machine: camera }\n  - id: b\n    deploy: { machine: compute, working_dir: /srv }\n",
        )
        .expect("yaml");
        set_working_dirs(&mut g, Path::new("/home/u/graphs"));
        assert_eq!(
            g["nodes"][0]["deploy"]["working_dir"].as_str(),
            Some("/home/u/graphs")
        );
        assert_eq!(
            g["nodes"][1]["deploy"]["working_dir"].as_str(),
            Some("/srv")
        );
        graph::strip_deploy(&mut g);
        assert!(g["nodes"][0].get("deploy").is_none() && g["nodes"][1].get("deploy").is_none());
    }

    #[test]
    fn node_lines_and_failures_of_dora_start_are_picked_out() {
        assert_eq!(
            node_line("20:15:44 stdout sink on daemon `compute`:  INFO summary written"),
            Some(("sink", "INFO summary written"))
        );
        assert_eq!(
            node_line("20:15:44 INFO   [dora] on daemon `camera`: x"),
            None
        );
        assert_eq!(node_line("short"), None);
        let text = "dataflow start triggered: 1\n\n[ERROR]\nNode `represent` failed: exited because of signal SIGKILL with stderr output:\n----\nLocation:\n    x.rs:1\n\nStack backtrace:\n  0: Node `fake` failed: no\n";
        assert_eq!(
            relay(text.as_bytes()),
            [(
                "represent".to_string(),
                "exited because of signal SIGKILL with stderr output:".to_string()
            )]
        );
    }

    #[test]
    fn a_coordinator_is_an_address_and_an_optional_port() {
        let at = |s: &str| match parse_coordinator(s).expect(s) {
            Cluster::Existing { coordinator, port } => (coordinator.to_string(), port),
            Cluster::Start { .. } => unreachable!(),
        };
        assert_eq!(at("10.0.0.2"), ("10.0.0.2".into(), 6013));
        assert_eq!(at("10.0.0.2:7000"), ("10.0.0.2".into(), 7000));
        assert_eq!(at("[fd00::2]:7000"), ("fd00::2".into(), 7000));
        assert_eq!(at("fd00::2"), ("fd00::2".into(), 6013));
        assert!(parse_coordinator("host.lan").is_err());
        assert!(parse_coordinator("10.0.0.2:x").is_err());
    }
}
