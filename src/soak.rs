//! `neuspike bench-live --soak`: what a long live run does to memory and latency. The resident
//! memory of this program (whose embedded daemon runs the graph) and of every node process is
//! sampled once a second into `rss.csv`; the sink's summary gives the latency of each minute.
//!
//! The verdicts, each stated so that it can fail:
//! - memory is flat: for every process, the largest sample of the last minute is within 5% of its
//!   sample at the second second (Linux: `/proc/<pid>/status` `VmRSS`; elsewhere nothing is
//!   sampled and the verdict says so);
//! - nothing is lost: the sink received every frame it expected;
//! - latency does not grow: the last full minute's p99 is at most 1.25 times the median of the
//!   minutes' p99s plus 1 ms (one busy minute is allowed; a trend is not).

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use eyre::WrapErr;
use neuspike_sink::report::LatencyWindow;

/// Resident memory may grow by this fraction between the second second and the last minute.
pub const RSS_TOLERANCE: f64 = 0.05;

/// One memory sample.
#[derive(Clone, Debug, PartialEq)]
pub struct RssSample {
    /// Seconds since sampling started.
    pub t_s: u64,
    /// `neuspike` (this program, the daemon) or the node binary's name.
    pub process: String,
    /// Resident set, KiB.
    pub rss_kib: u64,
}

/// `VmRSS` of `/proc/<pid>/status`, KiB.
fn rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// This process and its node children, as (pid, name).
fn processes() -> Vec<(u32, String)> {
    let mut v = vec![(std::process::id(), "neuspike".to_string())];
    v.extend(node_children());
    v
}

/// The children of this process whose name starts with `neuspike-` (the nodes an embedded daemon
/// spawned), as (pid, program name); empty where `/proc` cannot be read.
pub fn node_children() -> Vec<(u32, String)> {
    let me = std::process::id();
    let mut v = Vec::new();
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return v;
    };
    for e in dir.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
            continue;
        };
        // `pid (comm) state ppid ...`; comm may hold spaces, so split after its last `)`.
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        let comm = &stat[open + 1..close];
        let ppid = stat[close + 1..]
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse::<u32>().ok());
        if ppid == Some(me) && comm.starts_with("neuspike-") {
            // comm is cut at 15 bytes: the program's name from its command line instead.
            let name = std::fs::read(e.path().join("cmdline"))
                .ok()
                .and_then(|c| {
                    let argv0 = c.split(|b| *b == 0).next()?.to_vec();
                    let argv0 = String::from_utf8(argv0).ok()?;
                    Some(
                        Path::new(&argv0)
                            .file_name()?
                            .to_string_lossy()
                            .into_owned(),
                    )
                })
                .unwrap_or_else(|| comm.to_string());
            v.push((pid, name));
        }
    }
    v
}

/// Samples every second into `csv` until `done`; returns the samples.
pub fn spawn_sampler(
    csv: PathBuf,
    done: Arc<AtomicBool>,
) -> std::thread::JoinHandle<eyre::Result<Vec<RssSample>>> {
    std::thread::spawn(move || {
        let mut file = std::fs::File::create(&csv)
            .wrap_err_with(|| format!("cannot create {}", csv.display()))?;
        writeln!(file, "t_s,process,rss_kib")
            .wrap_err_with(|| format!("cannot write {}", csv.display()))?;
        let start = Instant::now();
        let mut samples = Vec::new();
        let mut next = Duration::ZERO;
        while !done.load(Ordering::Relaxed) {
            let now = start.elapsed();
            if now < next {
                std::thread::sleep((next - now).min(Duration::from_millis(100)));
                continue;
            }
            let t_s = next.as_secs();
            next += Duration::from_secs(1);
            for (pid, process) in processes() {
                if let Some(rss_kib) = rss_kib(pid) {
                    writeln!(file, "{t_s},{process},{rss_kib}")
                        .wrap_err_with(|| format!("cannot write {}", csv.display()))?;
                    samples.push(RssSample {
                        t_s,
                        process,
                        rss_kib,
                    });
                }
            }
        }
        Ok(samples)
    })
}

/// Per process: (sample at 2 s, largest of the last minute) in KiB. A process without both is
/// left out.
pub fn rss_flatness(samples: &[RssSample]) -> BTreeMap<String, (u64, u64)> {
    let end = samples.iter().map(|s| s.t_s).max().unwrap_or(0);
    let from = end.saturating_sub(59);
    let mut by: BTreeMap<String, (Option<u64>, Option<u64>)> = BTreeMap::new();
    for s in samples {
        let e = by.entry(s.process.clone()).or_default();
        if s.t_s == 2 {
            e.0 = Some(s.rss_kib);
        }
        if s.t_s >= from {
            e.1 = Some(e.1.map_or(s.rss_kib, |m: u64| m.max(s.rss_kib)));
        }
    }
    by.into_iter()
        .filter_map(|(k, v)| Some((k, (v.0?, v.1?))))
        .collect()
}

/// Whether the last minute's p99 stays within 1.25 x the median of the minutes' p99s + 1 ms:
/// (last p99, bound, verdict); `None` with fewer than two minutes.
pub fn latency_steady(minutes: &[LatencyWindow]) -> Option<(f64, f64, bool)> {
    // The run's last seconds make a short last window: it is left out when it holds less than
    // half a full one.
    let full = minutes.iter().map(|w| w.latency.frames).max().unwrap_or(0);
    let minutes = match minutes.split_last() {
        Some((last, rest)) if rest.len() >= 2 && last.latency.frames * 2 < full => rest,
        _ => minutes,
    };
    if minutes.len() < 2 {
        return None;
    }
    let mut p99: Vec<f64> = minutes.iter().map(|w| w.latency.p99_ms).collect();
    let last = *p99.last()?;
    p99.sort_by(f64::total_cmp);
    let median = p99[p99.len() / 2];
    let bound = 1.25 * median + 1.0;
    Some((last, bound, last <= bound))
}

/// Prints the soak's tables and verdicts; an error when a verdict fails.
pub fn report(
    samples: &[RssSample],
    minutes: &[LatencyWindow],
    missing: u64,
    csv: &Path,
) -> eyre::Result<()> {
    let mut failed = Vec::new();
    println!("\nResident memory ({}), KiB:\n", csv.display());
    println!("| process | at 2 s | last minute, largest | growth |\n|---|---:|---:|---:|");
    let flat = rss_flatness(samples);
    for (process, (early, late)) in &flat {
        let growth = *late as f64 / (*early).max(1) as f64 - 1.0;
        println!("| {process} | {early} | {late} | {:+.1}% |", growth * 100.0);
        if growth > RSS_TOLERANCE {
            failed.push(format!(
                "{process}'s memory grew {:.1}% (more than {:.0}%)",
                growth * 100.0,
                RSS_TOLERANCE * 100.0
            ));
        }
    }
    if flat.is_empty() {
        println!("(no samples: resident memory is read from /proc, on Linux only)");
    }
    println!(
        "\nLatency by minute (sink):\n\n| from s | frames | p50 ms | p99 ms | max ms |\n|---:|---:|---:|---:|---:|"
    );
    for w in minutes {
        let l = w.latency;
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.2} |",
            w.start_s, l.frames, l.p50_ms, l.p99_ms, l.max_ms
        );
    }
    match latency_steady(minutes) {
        Some((last, bound, ok)) => {
            println!(
                "\nlast minute's p99 {last:.2} ms, bound {bound:.2} ms (1.25 x the median + 1 ms)"
            );
            if !ok {
                failed.push(format!(
                    "latency p99 grew to {last:.2} ms (bound {bound:.2} ms)"
                ));
            }
        }
        None => println!("\n(less than two minutes: latency trend not judged)"),
    }
    if missing > 0 {
        failed.push(format!("{missing} frames lost"));
    }
    if failed.is_empty() {
        println!("soak: memory flat, nothing lost, latency steady");
        Ok(())
    } else {
        eyre::bail!("soak failed: {}", failed.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_sink::report::Latency;

    fn s(t_s: u64, process: &str, rss_kib: u64) -> RssSample {
        RssSample {
            t_s,
            process: process.into(),
            rss_kib,
        }
    }

    #[test]
    fn flatness_compares_the_second_second_with_the_last_minutes_largest() {
        let mut v = Vec::new();
        for t in 0..=200 {
            v.push(s(t, "sink", 1000 + t)); // grows 1 KiB a second
            v.push(s(t, "align", if t == 100 { 5000 } else { 800 }));
        }
        v.push(s(3, "late", 10)); // no sample at 2 s: left out
        let f = rss_flatness(&v);
        assert_eq!(f["sink"], (1002, 1200));
        // A spike before the last minute does not count.
        assert_eq!(f["align"], (800, 800));
        assert!(!f.contains_key("late"));
        assert!(
            report(&v, &[], 0, Path::new("rss.csv")).is_err(),
            "sink grew 19.8%"
        );
    }

    #[test]
    fn latency_is_steady_unless_the_last_minute_outgrows_the_median() {
        let w = |p99_ms: f64| LatencyWindow {
            start_s: 0,
            latency: Latency {
                frames: 100,
                p50_ms: 1.0,
                p99_ms,
                max_ms: p99_ms,
            },
        };
        assert_eq!(latency_steady(&[w(5.0)]), None);
        assert_eq!(
            latency_steady(&[w(4.0), w(8.0), w(5.0)]),
            Some((5.0, 7.25, true))
        );
        assert_eq!(
            latency_steady(&[w(4.0), w(4.0), w(4.0), w(9.0)]),
            Some((9.0, 6.0, false))
        );
        assert!(report(&[], &[w(4.0), w(4.0), w(9.0)], 0, Path::new("x")).is_err());
        assert!(report(&[], &[w(4.0), w(4.0)], 1, Path::new("x")).is_err());
        assert!(report(&[], &[w(4.0), w(4.0)], 0, Path::new("x")).is_ok());
        // A short last window (the run's last seconds) is left out.
        let mut short = w(50.0);
        short.latency.frames = 10;
        assert_eq!(
            latency_steady(&[w(4.0), w(4.0), w(4.0), short]),
            Some((4.0, 6.0, true))
        );
    }
}
