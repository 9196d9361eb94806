//! Running a graph: its nodes' `build:` commands, then the dataflow on an embedded dora daemon.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use dora_daemon::{Daemon, LogDestination, RunDataflowOptions, flume};
use dora_message::SessionId;
use dora_message::common::{LogLevel, LogLevelOrStdout, LogMessage};
use dora_message::coordinator_to_cli::DataflowResult;
use dora_message::descriptor::Descriptor;
use eyre::{WrapErr, bail, eyre};
use neuspike_sink::report::SummaryFile;
use serde_yaml::Value;

/// The message types of `schemas/types`, built in: written beside every graph the program writes
/// (dora reads user types from a `types/` folder beside the graph).
const MESSAGE_TYPES: &str = include_str!("../schemas/types/neuspike/messages/v1.yml");

/// Writes the message types into `dir/types/` (beside a graph written there).
pub fn write_types(dir: &Path) -> eyre::Result<()> {
    let types = dir.join("types/neuspike/messages");
    let file = types.join("v1.yml");
    std::fs::create_dir_all(&types)
        .and_then(|()| std::fs::write(&file, MESSAGE_TYPES))
        .wrap_err_with(|| format!("cannot write the message types to {}", file.display()))
}

/// The folder of the node binaries: the running program's own (the folder above it when it is a
/// test harness in cargo's `deps/`).
pub fn node_dir() -> eyre::Result<PathBuf> {
    let exe = std::env::current_exe().wrap_err("cannot tell where this program lives")?;
    let dir = exe.parent().unwrap_or(Path::new(".")).to_path_buf();
    Ok(match (dir.file_name(), dir.parent()) {
        (Some(n), Some(up)) if n == "deps" => up.to_path_buf(),
        _ => dir,
    })
}

/// The source checkout this program was built from, when it runs from a cargo build of that
/// checkout (`cargo run`, the tests; its `target/` or the `CARGO_TARGET_DIR` it was built into):
/// node binaries are built beside it. `None` for an installed or copied program, and when the
/// checkout has moved.
pub fn source_checkout() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).canonicalize().ok()?;
    if !dir.join("Cargo.toml").is_file() {
        return None;
    }
    let nodes = node_dir().ok()?.canonicalize().ok()?;
    let holds_nodes = |target: &Path| target.canonicalize().is_ok_and(|t| nodes.starts_with(t));
    // `cargo run` and `cargo test` tell the program its package's folder.
    let run_by_cargo = std::env::var_os("CARGO_MANIFEST_DIR")
        .is_some_and(|d| Path::new(&d).canonicalize().is_ok_and(|d| d == dir));
    let in_target_dir =
        std::env::var_os("CARGO_TARGET_DIR").is_some_and(|t| holds_nodes(Path::new(&t)));
    (holds_nodes(&dir.join("target")) || run_by_cargo || in_target_dir).then_some(dir)
}

/// The command that builds the node binaries in the source checkout, if there is one.
pub fn build_command() -> Option<String> {
    source_checkout().map(|dir| {
        format!(
            "cargo build --release --manifest-path {} --workspace --bins",
            dir.join("Cargo.toml").display()
        )
    })
}

/// Builds the node binaries when the program runs from its source checkout; does nothing for an
/// installed program.
pub fn build_nodes() -> eyre::Result<()> {
    match build_command() {
        Some(cmd) => run_build(&cmd, Path::new(".")),
        None => Ok(()),
    }
}

/// The binary of node `name` (`neuspike-align`, ...) beside this program; a missing one is an
/// error saying how to build it.
pub fn node_binary(name: &str) -> eyre::Result<PathBuf> {
    let dir = node_dir()?;
    let bin = dir.join(name);
    if bin.is_file() {
        return Ok(bin);
    }
    bail!(
        "node binary {name} is not beside this program in {}: build the nodes with `cargo build --release --workspace --bins` in the neuspike sources and keep target/release/neuspike-* together",
        dir.display()
    )
}

/// This program and the stage it runs as node binary `name` (`neuspike-align`: `align`), when
/// this program is `neuspike` (not a test harness) and serves that stage (`neuspike node`).
fn serving(name: &str) -> Option<(PathBuf, &str)> {
    let kind = name.strip_prefix("neuspike-")?;
    let exe = std::env::current_exe().ok()?;
    let stem = exe.file_stem()?.to_str()?;
    (stem == "neuspike" && crate::node::serves(kind)).then_some((exe, kind))
}

/// Points every node whose `path:` names a neuspike node binary (`neuspike-*`) at that binary
/// beside this program, or else at the graph's own path when it exists, or else at this program
/// itself as that stage's node (`neuspike node KIND`, an installed `neuspike` without the node
/// binaries).
pub fn resolve_node_binaries(graph: &mut Value, graph_dir: &Path) -> eyre::Result<()> {
    let list = graph.get_mut("nodes").and_then(Value::as_sequence_mut);
    for node in list.into_iter().flatten() {
        let Some(path) = node.get("path").and_then(Value::as_str).map(PathBuf::from) else {
            continue;
        };
        let Some(name) = path
            .file_name()
            .and_then(|n| n.to_str())
            .map(str::to_string)
        else {
            continue;
        };
        if !name.starts_with("neuspike-") {
            continue;
        }
        let bin = match node_binary(&name) {
            Ok(bin) => bin,
            Err(_) if graph_dir.join(&path).is_file() => continue,
            Err(e) => {
                // This program serves as the stage's node itself (an installed `neuspike`).
                let Some((exe, kind)) = serving(&name) else {
                    return Err(e);
                };
                let args = node.get("args").and_then(Value::as_str).unwrap_or("");
                let args = format!("node {kind} {args}");
                if let Some(map) = node.as_mapping_mut() {
                    map.insert("path".into(), exe.display().to_string().into());
                    map.insert("args".into(), args.trim_end().into());
                }
                continue;
            }
        };
        if let Some(map) = node.as_mapping_mut() {
            map.insert(Value::from("path"), Value::from(bin.display().to_string()));
        }
    }
    Ok(())
}

/// `NODE=ARGS` from the command line.
pub fn parse_override(s: &str) -> eyre::Result<(String, String)> {
    match s.split_once('=') {
        Some((node, args)) if !node.is_empty() => Ok((node.to_string(), args.to_string())),
        _ => bail!("--set `{s}`: expected NODE=ARGS, e.g. spike-source=\"--scene dark-slow\""),
    }
}

fn read_graph(path: &Path) -> eyre::Result<Value> {
    neuspike_pipeline::read_graph(path)
}

fn nodes(graph: &Value) -> impl Iterator<Item = &Value> {
    graph
        .get("nodes")
        .and_then(Value::as_sequence)
        .into_iter()
        .flatten()
}

/// Writes a graph built into the program (`text`) into `out` as `graph.yml`, ready to run from
/// there: no `build:` keys, each node's `args:` replaced by `args(id, old_args)` where that gives
/// one, its nodes the binaries beside this program, the message types beside it. `by` names the
/// command in the file's first line. Returns the graph's path.
///
/// # Errors
/// `text` is not YAML, a node binary is missing, or a file cannot be written.
pub fn write_built_in(
    text: &str,
    out: &Path,
    by: &str,
    args: impl Fn(&str, &str) -> Option<String>,
) -> eyre::Result<PathBuf> {
    let mut g: Value = serde_yaml::from_str(text)
        .wrap_err_with(|| format!("{by}: the built-in graph is not YAML"))?;
    let list = g.get_mut("nodes").and_then(Value::as_sequence_mut);
    for node in list.into_iter().flatten() {
        let Some(map) = node.as_mapping_mut() else {
            continue;
        };
        let id = map.get("id").and_then(Value::as_str).unwrap_or("");
        let old = map.get("args").and_then(Value::as_str).unwrap_or("");
        if let Some(new) = args(id, old) {
            map.insert("args".into(), new.into());
        }
    }
    neuspike_pipeline::derive::derive(&mut g, neuspike_pipeline::derive::CREDIT_WINDOW, None)
        .wrap_err_with(|| format!("{by}: the built-in graph"))?;
    // Built beforehand when the program runs from its sources; never from `out`.
    let list = g.get_mut("nodes").and_then(Value::as_sequence_mut);
    for node in list.into_iter().flatten() {
        if let Some(map) = node.as_mapping_mut() {
            map.remove("build");
        }
    }
    // The graph's relative paths mean nothing in `out`: every node runs the binary beside this
    // program, and a missing one is an error saying how to build it.
    resolve_node_binaries(&mut g, out)?;
    write_types(out)?;
    let path = out.join("graph.yml");
    let body =
        serde_yaml::to_string(&g).wrap_err_with(|| format!("{by}: cannot write the graph"))?;
    neuspike_formats::atomic::write(&path, format!("# Written by `{by}`.\n{body}"))
        .wrap_err_with(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

/// Writes `graph` (prepared: derived, its nodes pointed at their binaries) to `out` for the stock
/// dora CLI: the message types into `types/` beside it, every relative `path:` made absolute
/// from `graph_path`'s folder, the nodes' `build:` commands put back where this program runs
/// from its sources. dora runs the nodes in the written graph's folder: relative paths in their
/// arguments (a sink's `--out`) hold when it is written beside the original.
///
/// # Errors
/// A file cannot be written.
pub fn write_full(graph: &mut Value, graph_path: &Path, out: &Path) -> eyre::Result<()> {
    let graph_dir = graph_path.parent().unwrap_or(Path::new("."));
    let build = build_command();
    let list = graph.get_mut("nodes").and_then(Value::as_sequence_mut);
    for node in list.into_iter().flatten() {
        let Some(map) = node.as_mapping_mut() else {
            continue;
        };
        if let Some(p) = map.get("path").and_then(Value::as_str)
            && Path::new(p).is_relative()
            && graph_dir.join(p).exists()
        {
            let abs = graph_dir.join(p).display().to_string();
            map.insert("path".into(), abs.into());
        }
        let neuspike = map.get("path").and_then(Value::as_str).is_some_and(|p| {
            p.rsplit('/')
                .next()
                .is_some_and(|f| f.starts_with("neuspike-"))
        });
        if let (Some(cmd), true) = (&build, neuspike) {
            map.insert("build".into(), Value::from(cmd.clone()));
        }
    }
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).wrap_err_with(|| format!("cannot create {}", dir.display()))?;
    write_types(dir)?;
    let body = serde_yaml::to_string(graph).wrap_err("cannot write the graph")?;
    neuspike_formats::atomic::write(
        out,
        format!(
            "# Written by `neuspike graph` from {}: run it with `dora run` or `neuspike run`.\n{body}",
            graph_path.display()
        ),
    )
    .wrap_err_with(|| format!("cannot write {}", out.display()))
}

/// Appends `extra` to the `args:` of node `id`; an unknown node is an error.
fn apply_override(graph: &mut Value, id: &str, extra: &str) -> eyre::Result<()> {
    let list = graph.get_mut("nodes").and_then(Value::as_sequence_mut);
    let node = list
        .into_iter()
        .flatten()
        .find(|n| n.get("id").and_then(Value::as_str) == Some(id))
        .ok_or_else(|| eyre!("--set: the graph has no node `{id}`"))?;
    let old = node
        .get("args")
        .and_then(Value::as_str)
        .unwrap_or("")
        .to_string();
    if let Some(map) = node.as_mapping_mut() {
        map.insert(
            Value::from("args"),
            Value::from(format!("{old} {extra}").trim().to_string()),
        );
    }
    Ok(())
}

/// The `--out` folder of every sink node of a graph, resolved against the graph's folder.
pub fn sink_out_dirs(graph_path: &Path, graph: &Value) -> Vec<PathBuf> {
    let dir = graph_path.parent().unwrap_or(Path::new("."));
    // A sink may run inside a fused node.
    let inner: Vec<Value> = nodes(graph)
        .flat_map(neuspike_pipeline::derive::fused_nodes)
        .collect();
    nodes(graph)
        .chain(inner.iter())
        .filter(|n| {
            n.get("path")
                .and_then(Value::as_str)
                .is_some_and(|p| p.ends_with("neuspike-sink"))
        })
        .map(|n| {
            let args = n.get("args").and_then(Value::as_str).unwrap_or("");
            let words: Vec<&str> = args.split_whitespace().collect();
            let mut out = "out".to_string();
            for (i, w) in words.iter().enumerate() {
                if let Some(v) = w.strip_prefix("--out=") {
                    out = v.to_string();
                } else if *w == "--out"
                    && let Some(v) = words.get(i + 1)
                {
                    out = v.to_string();
                }
            }
            dir.join(out)
        })
        .collect()
}

/// Runs each distinct `build:` command of the graph in the graph's folder.
fn build(graph_path: &Path, graph: &Value) -> eyre::Result<()> {
    let dir = graph_path.parent().unwrap_or(Path::new("."));
    let mut done: Vec<&str> = Vec::new();
    for cmd in nodes(graph).filter_map(|n| n.get("build").and_then(Value::as_str)) {
        if done.contains(&cmd) {
            continue;
        }
        done.push(cmd);
        run_build(cmd, dir)?;
    }
    Ok(())
}

/// Whether cargo set the environment variable `name` for the program it runs (`cargo run`,
/// `cargo test`). A build started from such a program must not inherit them: build scripts (ring's,
/// cc's) watch variables like `CARGO_MANIFEST_DIR` and `CARGO_PKG_NAME`, and cargo compares the
/// values in its own environment, so an inherited one reruns them and recompiles everything above
/// them (zenoh and dora: minutes).
fn set_by_cargo(name: &str) -> bool {
    const EXACT: [&str; 8] = [
        "CARGO_MANIFEST_DIR",
        "CARGO_MANIFEST_PATH",
        "CARGO_MANIFEST_LINKS",
        "CARGO_CRATE_NAME",
        "CARGO_BIN_NAME",
        "CARGO_PRIMARY_PACKAGE",
        "CARGO_TARGET_TMPDIR",
        "OUT_DIR",
    ];
    EXACT.contains(&name) || name.starts_with("CARGO_PKG_") || name.starts_with("CARGO_BIN_EXE_")
}

/// Runs one build command in `dir`, without the variables cargo set for this program.
fn run_build(cmd: &str, dir: &Path) -> eyre::Result<()> {
    tracing::info!("build: {cmd}");
    let mut command = Command::new("sh");
    for (name, _) in std::env::vars_os() {
        if name.to_str().is_some_and(set_by_cargo) {
            command.env_remove(&name);
        }
    }
    let status = command
        .arg("-c")
        .arg(cmd)
        .current_dir(dir)
        .status()
        .wrap_err_with(|| format!("cannot start the build command `{cmd}`"))?;
    if !status.success() {
        bail!("the build command `{cmd}` failed ({status})");
    }
    Ok(())
}

/// What a run produced.
pub struct Report {
    /// The nodes that failed, sorted by id, with the cause dora gave.
    pub failures: Vec<(String, String)>,
    /// Output folders of the graph's sinks.
    pub out_dirs: Vec<PathBuf>,
    /// Wall time of the dataflow, from its start to the end of its last node (builds excluded).
    pub elapsed: Duration,
    /// When the dataflow started: files older than this are an earlier run's.
    pub started_at: std::time::SystemTime,
    /// The nodes' log files (dora's `out/<run>/` beside the graph), kept when a node failed and
    /// removed after a clean run.
    pub logs: Option<PathBuf>,
}

impl Report {
    /// Prints failures, where the outputs are, and each sink's summary.
    pub fn print(&self) {
        for (node, cause) in &self.failures {
            eprintln!("node `{node}` failed: {cause}");
        }
        if let Some(logs) = &self.logs {
            eprintln!("node logs: {}", logs.display());
        }
        println!(
            "ran in {:.2} s (wall, builds excluded)",
            self.elapsed.as_secs_f64()
        );
        for dir in &self.out_dirs {
            let dir = dir.canonicalize().unwrap_or_else(|_| dir.clone());
            println!("frames:  {}/<method>/*.png", dir.display());
            println!("metrics: {}", dir.join("metrics.csv").display());
            // Only a summary this run wrote: an earlier run's is never shown as this one's.
            let summary = dir.join("summary.md");
            let fresh = std::fs::metadata(&summary)
                .and_then(|m| m.modified())
                .is_ok_and(|t| t >= self.started_at);
            match std::fs::read_to_string(&summary) {
                Ok(s) if fresh => println!("summary: {}\n\n{s}", summary.display()),
                _ => println!("summary: none written by this run (the sink did not finish)"),
            }
        }
    }

    /// The nodes that failed, sorted by id.
    pub fn failed_nodes(&self) -> Vec<String> {
        self.failures.iter().map(|(n, _)| n.clone()).collect()
    }

    /// What this run's sinks say was lost or cut: `<folder>: <input>: N missing, cut short,
    /// never ended` for each input that did not come whole, and a `metrics.csv` that does not
    /// hold the rows its summary counts (none when no sink wrote a summary).
    pub fn losses(&self) -> Vec<String> {
        let mut out = Vec::new();
        for dir in &self.out_dirs {
            let path = dir.join("summary.yml");
            let fresh = std::fs::metadata(&path)
                .and_then(|m| m.modified())
                .is_ok_and(|t| t >= self.started_at);
            let Some(file) = fresh
                .then(|| std::fs::read_to_string(&path).ok())
                .flatten()
                .and_then(|t| serde_yaml::from_str::<SummaryFile>(&t).ok())
            else {
                continue;
            };
            for (input, f) in &file.inputs {
                let c = &f.counts;
                if c.missing == 0 && !c.cut && c.ended {
                    continue;
                }
                let mut what = vec![format!("{} of {} missing", c.missing, c.expected)];
                if c.cut {
                    what.push("cut short".into());
                }
                if !c.ended {
                    what.push("never ended".into());
                }
                out.push(format!("{}: {input}: {}", dir.display(), what.join(", ")));
            }
            // A sink that failed says so as a failed node; otherwise its metrics.csv must hold
            // every row its summary counts.
            if file.failure.is_none()
                && let Err(e) = neuspike_sink::read_run(dir)
            {
                out.push(e.to_string());
            }
        }
        out
    }

    /// An error when any node failed, or a sink's input lost or cut data.
    pub fn into_result(self) -> eyre::Result<()> {
        if !self.failures.is_empty() {
            return Err(eyre!(
                "the graph failed: nodes {}",
                self.failed_nodes().join(", ")
            ));
        }
        let lost = self.losses();
        if lost.is_empty() {
            Ok(())
        } else {
            Err(eyre!("the run lost data: {}", lost.join("; ")))
        }
    }
}

/// Whether a node of `graph` has a `restart_policy` other than `never`.
fn restarts_nodes(graph: &Value) -> bool {
    graph
        .get("nodes")
        .and_then(Value::as_sequence)
        .into_iter()
        .flatten()
        .filter_map(|n| n.get("restart_policy").and_then(Value::as_str))
        .any(|p| p != "never")
}

/// Reads the graph at `graph_path` (canonical), appends the `--set` overrides to its nodes'
/// arguments, derives what the runtime needs beyond its nodes, arguments and data edges
/// ([`neuspike_pipeline::derive::derive`]), runs its build commands (when `build_first`) and points its
/// nodes at the node binaries; the `build:` keys are removed (done).
///
/// # Errors
/// The graph cannot be read, names an unknown node in an override, a build fails, or a node
/// binary is missing.
pub fn prepare(
    graph_path: &Path,
    overrides: &[(String, String)],
    build_first: bool,
) -> eyre::Result<Value> {
    let mut graph = read_graph(graph_path)?;
    for (id, extra) in overrides {
        apply_override(&mut graph, id, extra)?;
    }
    neuspike_pipeline::derive::derive(
        &mut graph,
        neuspike_pipeline::derive::CREDIT_WINDOW,
        build_command().as_deref(),
    )
    .wrap_err_with(|| format!("{}", graph_path.display()))?;
    if build_first {
        build(graph_path, &graph)?;
    }
    resolve_node_binaries(&mut graph, graph_path.parent().unwrap_or(Path::new(".")))?;
    let list = graph.get_mut("nodes").and_then(Value::as_sequence_mut);
    for node in list.into_iter().flatten() {
        if let Some(map) = node.as_mapping_mut() {
            map.remove("build");
        }
    }
    Ok(graph)
}

/// Runs a graph: build commands (when `build`), then the dataflow on one embedded daemon, every
/// node on this machine whatever machine its `deploy:` names (`crate::cluster` runs a graph on
/// the machines it names). When `progress` names a sink folder, a spinner counts the frames
/// scored there.
pub fn run(
    graph_path: &Path,
    overrides: &[(String, String)],
    build_first: bool,
    stop_after: Option<Duration>,
    progress: Option<PathBuf>,
) -> eyre::Result<Report> {
    let graph_path = graph_path
        .canonicalize()
        .wrap_err_with(|| format!("graph {} not found", graph_path.display()))?;
    let mut graph = prepare(&graph_path, overrides, build_first)?;
    strip_deploy(&mut graph);
    let out_dirs = sink_out_dirs(&graph_path, &graph);
    // A lost backpressure message fails the run, except where dora restarts nodes: the credits
    // on their way to a producer that died are lost with it, and its new process is greeted
    // afresh (a loss of data is still a counted gap in the sequence numbers).
    let strict = !restarts_nodes(&graph);
    let started_at = std::time::SystemTime::now();
    let descriptor: Descriptor = serde_yaml::from_value(graph)
        .wrap_err_with(|| format!("{}: not a valid dora graph", graph_path.display()))?;

    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .wrap_err("cannot start the async runtime")?;
    let (log_tx, log_rx) = flume::bounded::<LogMessage>(1024);
    let printer = std::thread::spawn(move || {
        for m in log_rx {
            print_log(&m);
        }
    });
    let done = Arc::new(AtomicBool::new(false));
    let spinner = progress.map(|dir| spawn_progress(dir.join("metrics.csv"), done.clone()));
    let path = graph_path.clone();
    let started = std::time::Instant::now();
    let handle = rt.spawn(async move {
        Daemon::run_dataflow_with(
            None,
            &path,
            None,
            None,
            SessionId::generate(),
            false,
            LogDestination::Channel { sender: log_tx },
            None,
            stop_after,
            false,
            None,
            Some(descriptor),
            RunDataflowOptions::default().fail_on_lost_backpressure_messages(strict),
        )
        .await
    });
    let result = rt.block_on(handle);
    done.store(true, Ordering::Relaxed);
    if let Some(s) = spinner {
        let _ = s.join();
    }
    rt.shutdown_timeout(Duration::from_secs(10));
    let _ = printer.join();
    let result = result.wrap_err("the dataflow task panicked")??;
    let elapsed = started.elapsed();
    let logs = keep_logs_of_failure(graph_path.parent(), &result);
    let failures = result
        .node_results
        .iter()
        .filter_map(|(node, r)| r.as_ref().err().map(|e| (node.to_string(), e.to_string())))
        .collect();
    Ok(Report {
        failures,
        out_dirs,
        elapsed,
        started_at,
        logs,
    })
}

/// dora writes every node's log into `out/<run>/` beside the graph. Its lines were printed as
/// they came, so after a clean run the folder is removed (and `out/` with it when that leaves it
/// empty); after a failure it is kept and returned.
fn keep_logs_of_failure(graph_dir: Option<&Path>, result: &DataflowResult) -> Option<PathBuf> {
    let out = graph_dir?.join("out");
    let dir = out.join(result.uuid.to_string());
    if !dir.is_dir() {
        return None;
    }
    if !result.is_ok() {
        return Some(dir);
    }
    if let Err(e) = std::fs::remove_dir_all(&dir) {
        tracing::warn!("cannot remove the node logs {}: {e}", dir.display());
    }
    // Fails, as wanted, when another run's logs are still there.
    let _ = std::fs::remove_dir(&out);
    None
}

/// Prints a node's log line as `node | message`; the daemon's own lines only when they warn.
fn print_log(m: &LogMessage) {
    let from_daemon = m.target.as_deref().is_some_and(|t| t.contains("daemon"));
    // A second graph run in one process (`bench-live --runs`) finds the handler in place.
    if from_daemon && m.message.contains("ctrl-c handler already registered") {
        return;
    }
    match &m.node_id {
        Some(node) if !from_daemon => {
            eprintln!("{:>14} | {}", node.to_string(), m.message.trim_end())
        }
        _ if m.level.passes(&LogLevelOrStdout::LogLevel(LogLevel::Warn)) => {
            eprintln!("{:>14} | {}", "dora", m.message.trim_end())
        }
        _ => {}
    }
}

/// A spinner that counts the rows of a metrics CSV until `done`.
fn spawn_progress(csv: PathBuf, done: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let bar = indicatif::ProgressBar::new_spinner();
        bar.set_style(
            indicatif::ProgressStyle::with_template("{spinner} {elapsed} {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
        );
        while !done.load(Ordering::Relaxed) {
            let rows = std::fs::read_to_string(&csv)
                .map(|s| s.lines().count().saturating_sub(1))
                .unwrap_or(0);
            bar.set_message(format!("{rows} frames scored"));
            bar.tick();
            std::thread::sleep(Duration::from_millis(200));
        }
        bar.finish_and_clear();
    })
}

/// Removes every node's `deploy:`, so that the graph runs on one daemon.
pub fn strip_deploy(graph: &mut Value) {
    let list = graph.get_mut("nodes").and_then(Value::as_sequence_mut);
    for node in list.into_iter().flatten() {
        if let Some(map) = node.as_mapping_mut() {
            map.remove("deploy");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn credits_are_wired_from_every_consumer_back_to_its_producers() {
        let mut g: Value = serde_yaml::from_str(
            "nodes:\n  - id: src\n    outputs: [a, b, v]\n  - id: mid\n    inputs: { a: { source: src/a, queue_size: 1000 }, t: dora/timer/millis/10 }\n    outputs: [c]\n  - id: sink\n    inputs: { c: mid/c, b: src/b }\n  - id: viewer\n    inputs: { v: { source: src/v, queue_policy: backpressure } }\n",
        )
        .expect("yaml");
        neuspike_pipeline::derive::wire_credits(&mut g, 8);
        let node = |id: &str| {
            nodes(&g)
                .find(|n| n.get("id").and_then(Value::as_str) == Some(id))
                .cloned()
                .expect("node")
        };
        let (src, mid, sink) = (node("src"), node("mid"), node("sink"));
        assert_eq!(mid["inputs"]["a"]["queue_size"].as_u64(), Some(8));
        assert!(mid["inputs"]["a"]["queue_policy"].is_null());
        assert_eq!(mid["inputs"]["t"].as_str(), Some("dora/timer/millis/10"));
        assert_eq!(sink["inputs"]["b"]["source"].as_str(), Some("src/b"));
        assert_eq!(
            src["inputs"]["credits-mid"]["source"].as_str(),
            Some("mid/credits")
        );
        assert_eq!(
            src["inputs"]["credits-sink"]["queue_policy"].as_str(),
            Some("backpressure")
        );
        assert_eq!(
            mid["inputs"]["credits-sink"]["source"].as_str(),
            Some("sink/credits")
        );
        assert!(src["outputs"].as_sequence().is_some_and(|o| o.len() == 3));
        // An input left to dora's backpressure is not flow controlled by credits.
        let viewer = node("viewer");
        assert!(viewer["inputs"]["v"]["queue_size"].is_null());
        assert!(src["inputs"]["credits-viewer"].is_null() && viewer["outputs"].is_null());
        assert_eq!(mid["outputs"][1].as_str(), Some("credits"));
        assert_eq!(sink["outputs"][0].as_str(), Some("credits"));
        assert_eq!(
            sink["output_types"]["credits"].as_str(),
            Some("neuspike/messages/v1/Credit")
        );
        // Twice is once.
        let before = g.clone();
        neuspike_pipeline::derive::wire_credits(&mut g, 8);
        assert_eq!(g, before);
    }

    const GRAPH: &str = "nodes:\n  - id: src\n    path: ../target/release/neuspike-spike-source\n    args: --scene a\n  - id: sink\n    path: ../target/release/neuspike-sink\n    args: --bit-depth 8 --out ../out/x\n";

    #[test]
    fn a_graph_that_restarts_nodes_is_told_apart() {
        let g: Value = serde_yaml::from_str(GRAPH).unwrap();
        assert!(!restarts_nodes(&g));
        let g: Value =
            serde_yaml::from_str("nodes:\n  - id: a\n    restart_policy: on-failure\n").unwrap();
        assert!(restarts_nodes(&g));
        let g: Value =
            serde_yaml::from_str("nodes:\n  - id: a\n    restart_policy: never\n").unwrap();
        assert!(!restarts_nodes(&g));
    }

    #[test]
    fn overrides_append_to_args_and_name_unknown_nodes() {
        let mut g: Value = serde_yaml::from_str(GRAPH).unwrap();
        apply_override(&mut g, "src", "--scene b").unwrap();
        let args = nodes(&g)
            .next()
            .and_then(|n| n.get("args"))
            .and_then(Value::as_str);
        assert_eq!(args, Some("--scene a --scene b"));
        let e = apply_override(&mut g, "nope", "--x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`nope`"), "{e}");
        assert_eq!(
            parse_override("src=--scene c").unwrap(),
            ("src".into(), "--scene c".into())
        );
        assert!(parse_override("--scene c").is_err());
    }

    #[test]
    fn builds_do_not_inherit_what_cargo_set_for_this_program() {
        for name in [
            "CARGO_MANIFEST_DIR",
            "CARGO_PKG_NAME",
            "CARGO_PKG_VERSION_MAJOR",
            "CARGO_BIN_EXE_neuspike",
            "OUT_DIR",
        ] {
            assert!(set_by_cargo(name), "{name}");
        }
        for name in ["CARGO_HOME", "CARGO_TARGET_DIR", "RUSTFLAGS", "PATH"] {
            assert!(!set_by_cargo(name), "{name}");
        }
    }

    #[test]
    fn sink_out_dirs_resolve_against_the_graph_folder() {
        let g: Value = serde_yaml::from_str(GRAPH).unwrap();
        let dirs = sink_out_dirs(Path::new("/g/graphs/demo.yml"), &g);
        assert_eq!(dirs, vec![PathBuf::from("/g/graphs/../out/x")]);
    }
}
