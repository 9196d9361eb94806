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
use serde_yaml::Value;

/// `NODE=ARGS` from the command line.
pub fn parse_override(s: &str) -> eyre::Result<(String, String)> {
    match s.split_once('=') {
        Some((node, args)) if !node.is_empty() => Ok((node.to_string(), args.to_string())),
        _ => bail!("--set `{s}`: expected NODE=ARGS, e.g. spike-source=\"--scene dark-slow\""),
    }
}

fn read_graph(path: &Path) -> eyre::Result<Value> {
    let text = std::fs::read_to_string(path)
        .wrap_err_with(|| format!("cannot read the graph {}", path.display()))?;
    serde_yaml::from_str(&text)
        .wrap_err_with(|| format!("{}: not a valid YAML graph", path.display()))
}

fn nodes(graph: &Value) -> impl Iterator<Item = &Value> {
    graph
        .get("nodes")
        .and_then(Value::as_sequence)
        .into_iter()
        .flatten()
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
    nodes(graph)
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

/// The first sink's output folder of a graph file.
pub fn sink_out_dir(graph_path: &Path) -> eyre::Result<Option<PathBuf>> {
    let g = read_graph(graph_path)?;
    Ok(sink_out_dirs(graph_path, &g).into_iter().next())
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
        tracing::info!("build: {cmd}");
        let status = Command::new("sh")
            .arg("-c")
            .arg(cmd)
            .current_dir(dir)
            .status()
            .wrap_err_with(|| format!("cannot start the build command `{cmd}`"))?;
        if !status.success() {
            bail!("the build command `{cmd}` failed ({status})");
        }
    }
    Ok(())
}

/// What a run produced.
pub struct Report {
    /// Per-node results from the daemon.
    pub result: DataflowResult,
    /// Output folders of the graph's sinks.
    pub out_dirs: Vec<PathBuf>,
    /// Wall time of the dataflow, from its start to the end of its last node (builds excluded).
    pub elapsed: Duration,
}

impl Report {
    /// Prints failures, where the outputs are, and each sink's summary.
    pub fn print(&self) {
        for (node, r) in &self.result.node_results {
            if let Err(e) = r {
                eprintln!("node `{node}` failed: {e}");
            }
        }
        println!(
            "ran in {:.2} s (wall, builds excluded)",
            self.elapsed.as_secs_f64()
        );
        for dir in &self.out_dirs {
            let dir = dir.canonicalize().unwrap_or_else(|_| dir.clone());
            println!("frames:  {}/<method>/*.png", dir.display());
            println!("metrics: {}", dir.join("metrics.csv").display());
            match std::fs::read_to_string(dir.join("summary.md")) {
                Ok(s) => println!("summary: {}\n\n{s}", dir.join("summary.md").display()),
                Err(_) => println!("summary: none written (the sink did not finish)"),
            }
        }
    }

    /// An error when any node failed.
    pub fn into_result(self) -> eyre::Result<()> {
        if self.result.is_ok() {
            Ok(())
        } else {
            let failed: Vec<String> = self
                .result
                .node_results
                .iter()
                .filter(|(_, r)| r.is_err())
                .map(|(n, _)| n.to_string())
                .collect();
            Err(eyre!("the graph failed: nodes {}", failed.join(", ")))
        }
    }
}

/// Runs a graph: build commands (when `build`), then the dataflow on an embedded daemon. When
/// `progress` names a sink folder, a spinner counts the frames scored there.
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
    let mut graph = read_graph(&graph_path)?;
    for (id, extra) in overrides {
        apply_override(&mut graph, id, extra)?;
    }
    if build_first {
        build(&graph_path, &graph)?;
    }
    let out_dirs = sink_out_dirs(&graph_path, &graph);
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
            RunDataflowOptions::default().fail_on_lost_backpressure_messages(true),
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
    Ok(Report {
        result,
        out_dirs,
        elapsed,
    })
}

/// Prints a node's log line as `node | message`; the daemon's own lines only when they warn.
fn print_log(m: &LogMessage) {
    let from_daemon = m.target.as_deref().is_some_and(|t| t.contains("daemon"));
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

#[cfg(test)]
mod tests {
    use super::*;

    const GRAPH: &str = "nodes:\n  - id: src\n    path: ../target/release/neuspike-spike-source\n    args: --scene a\n  - id: sink\n    path: ../target/release/neuspike-sink\n    args: --bit-depth 8 --out ../out/x\n";

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
    fn sink_out_dirs_resolve_against_the_graph_folder() {
        let g: Value = serde_yaml::from_str(GRAPH).unwrap();
        let dirs = sink_out_dirs(Path::new("/g/graphs/demo.yml"), &g);
        assert_eq!(dirs, vec![PathBuf::from("/g/graphs/../out/x")]);
    }
}
