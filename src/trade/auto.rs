//! `auto` in the bench: the policy fitted from training rows, and its frames on held-out ones.
//!
//! For each scored window, the policy chooses from the window's statistics; `auto`'s frame is
//! the chosen method's frame of that window (every method runs each window exactly as in its
//! own pass), and its cost is the statistics' time plus the chosen method's time for that window
//! plus, every window, the median time of each other stateful method the policy names (a graph
//! keeps their state current so that they can be chosen at any window).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use eyre::{WrapErr, bail, eyre};
use ndarray::Array2;
use neuspike_reconstruction::policy::{Policy, Provenance};
use neuspike_representations::WindowStats;

use super::BenchOptions;
use super::run::{MethodSpec, Recording};
use super::table::{self, Row};

/// The method's name in the tables.
pub const NAME: &str = "auto";

/// Whether a row's method is `auto` or budget mode (`auto-<X>ms`): not a method of its own, so
/// left out of the oracle, the choices and the fit.
pub fn is_auto(method: &str) -> bool {
    method == NAME
        || method == REGIONS_NAME
        || (method.starts_with("auto-") && method.ends_with("ms"))
}

/// The name of per-region `auto`'s rows.
pub const REGIONS_NAME: &str = "auto-regions";

/// The tiles per-region `auto` cuts the 400x250 grid into (5 x 5).
pub const REGIONS_TILE: (usize, usize) = (80, 50);

/// The default policy file, under the models folder.
pub const DEFAULT_POLICY: &str = "policy.yml";

/// What `auto` takes from a method's passes over one recording.
pub struct Kept {
    /// Whether it keeps state across windows.
    pub stateful: bool,
    /// Its median window time, 1 and 2 threads.
    pub p50_ms: [f64; 2],
    /// The time of each scored window, 1 and 2 threads.
    pub scored_ms: [Vec<f64>; 2],
    /// Peak heap bytes.
    pub peak_bytes: usize,
    /// The frames of the scored windows (1 thread).
    pub frames: Vec<Array2<f32>>,
}

/// The policy the bench runs: `--policy`, else `models/policy.yml` when it exists; checked
/// against the installed methods.
///
/// # Errors
/// The policy does not load, or names a method not installed.
pub fn policy(
    opts: &BenchOptions,
    methods: &[MethodSpec],
) -> eyre::Result<Option<(std::path::PathBuf, Policy)>> {
    let path = match &opts.policy {
        Some(p) if p.as_os_str() == "none" => return Ok(None),
        Some(p) => p.clone(),
        None => {
            let p = opts.models.join(DEFAULT_POLICY);
            if !p.exists() {
                return Ok(None);
            }
            p
        }
    };
    let installed: Vec<&str> = methods.iter().map(|m| m.name.as_str()).collect();
    let p = Policy::load(&path, &installed).map_err(|e| eyre!("--policy: {e}"))?;
    Ok(Some((path, p)))
}

/// `auto`'s row on one recording.
///
/// # Errors
/// A method the policy chose was not run (a bug).
pub fn row(
    policy: &Policy,
    rec: &Recording,
    stats: &[(WindowStats, f64)],
    kept: &BTreeMap<String, Kept>,
    template: &Row,
) -> eyre::Result<Row> {
    let mut frames = Vec::with_capacity(stats.len());
    let mut ms = [Vec::new(), Vec::new()];
    let mut mix: BTreeMap<&str, usize> = BTreeMap::new();
    for (i, (s, stats_ms)) in stats.iter().enumerate() {
        let m = policy.choose(s);
        let k = kept
            .get(m)
            .ok_or_else(|| eyre!("auto: the policy chose {m}, which did not run"))?;
        frames.push(k.frames[i].clone());
        for (t, v) in ms.iter_mut().enumerate() {
            let upkeep: f64 = kept
                .iter()
                .filter(|(name, o)| o.stateful && name.as_str() != m)
                .map(|(_, o)| o.p50_ms[t])
                .sum();
            v.push(stats_ms + k.scored_ms[t][i] + upkeep);
        }
        *mix.entry(m).or_default() += 1;
    }
    let mut row = Row {
        method: NAME.to_string(),
        p50_1t_ms: table::percentile(&ms[0], 50.0),
        p99_1t_ms: table::percentile(&ms[0], 99.0),
        p50_2t_ms: table::percentile(&ms[1], 50.0),
        p99_2t_ms: table::percentile(&ms[1], 99.0),
        windows: stats.len(),
        // Every method the policy names may hold its state and buffers at once.
        peak_mib: if crate::memory::counting() {
            kept.values().map(|k| k.peak_bytes).sum::<usize>() as f64 / (1024.0 * 1024.0)
        } else {
            f64::NAN
        },
        ..template.clone()
    };
    super::score(&mut row, &frames, rec.truth.as_ref());
    row.label = mix_label(&template.label, mix.iter().map(|(m, n)| (*m, *n)), 0);
    Ok(row)
}

/// `x` to 2 decimals (the table is for reading).
fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// `x` to 6 significant decimals.
fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}

/// A row's label with the methods chosen and the frames late: `noise:7 [tfp-33 x3 tfstp x1 late
/// x1]` (the summary reads `late x` back).
fn mix_label<'a>(
    texture: &str,
    mix: impl Iterator<Item = (&'a str, usize)>,
    late: usize,
) -> String {
    let chosen: Vec<String> = mix.map(|(m, n)| format!("{m} x{n}")).collect();
    let late = if late > 0 {
        format!(" late x{late}")
    } else {
        String::new()
    };
    format!("{texture} [{}{late}]", chosen.join(" "))
}

/// The name of budget mode's rows: `auto-5ms` on one thread, `auto-5ms-2t` on two.
pub fn budget_name(budget_ms: f64, threads: usize) -> String {
    match threads {
        0 | 1 => format!("{NAME}-{budget_ms}ms"),
        n => format!("{NAME}-{budget_ms}ms-{n}t"),
    }
}

/// Budget mode on one recording, run by the infer node's own stage ([`neuspike_reconstruction::auto`])
/// on `threads` threads, as a node runs it ([`stage_row`]); a frame is late when its cost
/// exceeds the budget.
///
/// # Errors
/// The stage refused a window.
pub fn budget_row(
    stage: &mut neuspike_reconstruction::auto::Auto,
    (budget_ms, threads): (f64, usize),
    rec: &Recording,
    template: &Row,
) -> eyre::Result<(Row, usize)> {
    stage_row(
        stage,
        &budget_name(budget_ms, threads),
        threads,
        rec,
        template,
    )
}

/// A row of the infer node's own `auto` stage on one recording, on `threads` threads (its
/// networks' convolutions split across them), as a node runs it: 256-plane windows every 20 planes from plane 140 (the first a 256-plane window fits), the
/// scored ones kept. Its cost is the stage's own measure of each scored frame (statistics,
/// upkeep, representation, reconstruction); its label gives the frames per choice (per region:
/// the tiles per method) and the frames late (`exact` counts nothing here; `windows` is the
/// scored frames).
///
/// # Errors
/// The stage refused a window.
pub fn stage_row(
    stage: &mut neuspike_reconstruction::auto::Auto,
    name: &str,
    threads: usize,
    rec: &Recording,
    template: &Row,
) -> eyre::Result<(Row, usize)> {
    stage.reset();
    let threads = threads.max(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .wrap_err("cannot start a thread pool")?;
    neuspike_reconstruction::learned::set_threads(threads);
    let last = rec.scored.last().copied().unwrap_or(0);
    let refs: Vec<u64> = (140..=last)
        .step_by(super::grid::STRIDE_PLANES as usize)
        .collect();
    let cuts = rec.windows(256, &refs, false)?;
    let (frames, ms, mix, late) = pool.install(|| -> eyre::Result<_> {
        let mut frames = Vec::new();
        let mut ms = Vec::new();
        let mut mix: BTreeMap<String, usize> = BTreeMap::new();
        let mut late = 0;
        for cut in &cuts {
            let c = cut.window.ref_plane;
            let f = stage
                .frame(&cut.window)
                .map_err(|e| eyre!("auto: window at plane {c}: {e}"))?;
            if rec.scored.contains(&c) {
                ms.push(f.compute_ns as f64 / 1e6);
                if f.regions.is_empty() {
                    *mix.entry(f.method).or_default() += 1;
                } else {
                    for (m, n) in f.regions {
                        *mix.entry(m).or_default() += n;
                    }
                }
                late += usize::from(f.late);
                frames.push(f.data);
            }
        }
        Ok((frames, ms, mix, late))
    })?;
    let mut row = Row {
        method: name.to_string(),
        p50_1t_ms: table::percentile(&ms, 50.0),
        p99_1t_ms: table::percentile(&ms, 99.0),
        windows: ms.len(),
        ..template.clone()
    };
    super::score(&mut row, &frames, rec.truth.as_ref());
    row.label = mix_label(
        &template.label,
        mix.iter().map(|(m, n)| (m.as_str(), *n)),
        late,
    );
    Ok((row, late))
}

/// The UTC date and time now, RFC 3339 (civil date from the Unix day count).
pub(crate) fn now_utc() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Howard Hinnant's days-to-civil.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1_460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3_600,
        rem % 3_600 / 60,
        rem % 60
    )
}

/// Fits a policy from the CSV's training rows: one row per scene class, its method the one that
/// maximises mean PSNR minus `--db-per-ms` times its median ms on one thread.
///
/// # Errors
/// No training rows (fitting on held-out textures is refused: it would tune to the test).
pub fn fit(rows: &[Row], opts: &BenchOptions, csv: &Path) -> eyre::Result<Policy> {
    if opts.set.as_str() != "train" {
        bail!("--fit-policy fits on training textures only: add --set train");
    }
    if !(opts.db_per_ms.is_finite() && opts.db_per_ms >= 0.0) {
        bail!("--db-per-ms {}: must be finite and >= 0", opts.db_per_ms);
    }
    // The methods the infer node's `auto` runs: every one but the event filters and the fusion,
    // whose state lives across windows in the infer stage.
    let runnable = |m: &str| {
        !matches!(
            neuspike_reconstruction::policy::MethodName::parse(m),
            Ok(neuspike_reconstruction::policy::MethodName::Hf
                | neuspike_reconstruction::policy::MethodName::Cf
                | neuspike_reconstruction::policy::MethodName::Fusion
                | neuspike_reconstruction::policy::MethodName::FusionTfp)
                | Err(_)
        )
    };
    let train: Vec<Row> = rows
        .iter()
        .filter(|r| r.set == "train" && !is_auto(&r.method) && runnable(&r.method))
        .cloned()
        .collect();
    if train.is_empty() {
        bail!(
            "--fit-policy: {} has no rows of the train set",
            csv.display()
        );
    }
    let mut out = Vec::new();
    let mut classes = Vec::new();
    for (class, methods) in table::by(&train, |r| r.class.clone()) {
        let cands: Vec<(String, f64, f64)> = methods
            .iter()
            .map(|(m, rs)| {
                let s = table::summarise(rs);
                (m.clone(), s.psnr, s.p50_1t_ms)
            })
            .collect();
        let two_threads: BTreeMap<&str, f64> = methods
            .iter()
            .map(|(m, rs)| (m.as_str(), table::summarise(rs).p50_2t_ms))
            .collect();
        let Some(pick) = neuspike_reconstruction::policy::best_value(&cands, opts.db_per_ms) else {
            continue;
        };
        let best = cands
            .iter()
            .map(|c| c.1)
            .filter(|v| v.is_finite())
            .fold(f64::NAN, f64::max);
        let mut ranked: Vec<neuspike_reconstruction::policy::Ranked> = cands
            .iter()
            .filter(|c| c.1.is_finite() && c.2.is_finite())
            .map(|c| neuspike_reconstruction::policy::Ranked {
                method: c.0.clone(),
                psnr_db: round2(c.1),
                ms: (c.2 * 1_000.0).round() / 1_000.0,
                ms_2: two_threads
                    .get(c.0.as_str())
                    .filter(|v| v.is_finite())
                    .map(|v| (v * 1_000.0).round() / 1_000.0),
            })
            .collect();
        ranked.sort_by(|a, b| b.psnr_db.total_cmp(&a.psnr_db));
        classes.push(neuspike_reconstruction::policy::Class {
            class: class.clone(),
            method: pick.0.clone(),
            psnr_db: round2(pick.1),
            best_psnr_db: round2(best),
            ranked,
        });
        // One row per recording of the class (its statistics are the same in every method's
        // row): the table covers how textures move the statistics.
        let mut seen = std::collections::BTreeSet::new();
        for r in methods.iter().flat_map(|(_, rs)| rs.iter()) {
            if !seen.insert(r.texture) {
                continue;
            }
            out.push(neuspike_reconstruction::policy::Row {
                class: class.clone(),
                texture: r.label.clone(),
                rate: round6(r.rate),
                event_rate: round6(r.event_rate),
                change: round6(r.change),
                spread_decades: round6(r.spread_decades),
                edge: round6(r.edge),
            });
        }
    }
    // The program by its name, not the path it ran from.
    let command = std::iter::once("neuspike".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ");
    let p = Policy::new(
        Provenance {
            command,
            data: format!(
                "{} (`neuspike bench --set train`: {} rows, {} scene classes x {} textures)",
                csv.display(),
                train.len(),
                classes.len(),
                train
                    .iter()
                    .map(|r| r.texture)
                    .collect::<std::collections::BTreeSet<_>>()
                    .len()
            ),
            date: now_utc(),
        },
        opts.db_per_ms,
        classes,
        out,
    );
    let names: Vec<&str> = train.iter().map(|r| r.method.as_str()).collect();
    p.check(Some(&names))
        .map_err(|e| eyre!("--fit-policy: the fitted policy is invalid: {e}"))
        .wrap_err("a class without a finite PSNR?")?;
    Ok(p)
}

/// The summary's section on `auto`: against the oracle (each class's best method) and against
/// always running `neuspike-fused-16`, averaged over the scene classes.
pub fn summary(md: &mut String, rows: &[Row], policy: Option<&Policy>) {
    let scored: Vec<Row> = rows
        .iter()
        .filter(|r| r.set != "real" && r.psnr.is_finite())
        .cloned()
        .collect();
    if !scored.iter().any(|r| r.method == NAME) {
        return;
    }
    let _ = writeln!(
        md,
        "## auto: the method each window needs\n\n{}Per scene class: auto's mean PSNR against \
         the best method's (the oracle) and always-`neuspike-fused-16`'s; the cost of a frame on \
         one thread (ms, median over its windows), and the methods chosen.\n\n\
         | class | auto dB | oracle | oracle dB | fused-16 dB | auto ms | fused-16 ms | chosen |\n|---|---|---|---|---|---|---|---|",
        policy.map_or(String::new(), |p| format!(
            "Policy fitted by `{}` on {} ({}), {} dB per ms. ",
            p.provenance.command, p.provenance.data, p.provenance.date, p.db_per_ms
        ))
    );
    let (mut a, mut o, mut f, mut ac, mut fc) = (vec![], vec![], vec![], vec![], vec![]);
    let mut per_region: Vec<RegionCompare> = Vec::new();
    for (class, methods) in table::by(&scored, |r| r.class.clone()) {
        let per: Vec<(String, table::Summary)> = methods
            .iter()
            .map(|(m, rs)| (m.clone(), table::summarise(rs)))
            .collect();
        let get = |n: &str| per.iter().find(|(m, _)| m == n).map(|(_, s)| s.clone());
        let Some(auto) = get(NAME) else { continue };
        let others: Vec<(String, table::Summary)> =
            per.iter().filter(|(m, _)| !is_auto(m)).cloned().collect();
        let Some((best, _)) = table::choice(&others, 0.0) else {
            continue;
        };
        let oracle = get(&best).unwrap_or_default();
        let fused = get("neuspike-fused-16").unwrap_or_default();
        let chosen: Vec<String> = methods
            .iter()
            .filter(|(m, _)| m == NAME)
            .flat_map(|(_, rs)| {
                rs.iter().map(|r| {
                    r.label
                        .split_once(" [")
                        .map_or("", |x| x.1)
                        .trim_end_matches(']')
                        .to_string()
                })
            })
            .collect();
        let _ = writeln!(
            md,
            "| {class} | {} | {best} | {} | {} | {} | {} | {} |",
            table::fmt(auto.psnr, 2),
            table::fmt(oracle.psnr, 2),
            table::fmt(fused.psnr, 2),
            table::fmt(auto.p50_1t_ms, 2),
            table::fmt(fused.p50_1t_ms, 2),
            chosen.join("; ")
        );
        if let Some(r) = get(REGIONS_NAME) {
            per_region.push((class.clone(), auto.clone(), r, oracle.psnr));
        }
        a.push(auto.psnr);
        o.push(oracle.psnr);
        f.push(fused.psnr);
        ac.push(auto.p50_1t_ms);
        fc.push(fused.p50_1t_ms);
    }
    let budget: Vec<&Row> = rows
        .iter()
        .filter(|r| {
            r.set != "real" && r.method.starts_with(&format!("{NAME}-")) && r.method.ends_with("ms")
        })
        .collect();
    let budget_text = if budget.is_empty() {
        String::new()
    } else {
        let frames: usize = budget.iter().map(|r| r.frames).sum();
        let late: usize = budget
            .iter()
            .filter_map(|r| r.label.split(" late x").nth(1))
            .filter_map(|n| n.trim_end_matches(']').parse::<usize>().ok())
            .sum();
        let p99 = budget.iter().map(|r| r.p99_1t_ms).fold(f64::NAN, f64::max);
        format!(
            "Budget mode (`{}`, the infer node's own stage on one thread): {:.2} dB over the grid, \
             {late} of {frames} scored frames late ({:.2}%), the slowest {:.2} ms.\n\n",
            budget[0].method,
            table::mean(budget.iter().map(|r| r.psnr)),
            100.0 * late as f64 / frames.max(1) as f64,
            p99
        )
    };
    let (ma, mo, mf, mac, mfc) = (
        table::mean(a),
        table::mean(o),
        table::mean(f),
        table::mean(ac),
        table::mean(fc),
    );
    let _ = writeln!(
        md,
        "\nOver the grid: auto {:.2} dB, {:.1}% of the oracle's {:.2} dB; always-`neuspike-fused-16` \
         {:.2} dB (auto {:+.2} dB); auto's cost {:.2} ms a frame, {:.1}% of fused-16's {:.2} ms.\n\n{budget_text}",
        ma,
        100.0 * ma / mo,
        mo,
        mf,
        ma - mf,
        mac,
        100.0 * mac / mfc,
        mfc
    );
    regions_summary(md, rows, &per_region);
}

/// Per-region auto against auto: over the grid, and the classes where it gains and loses most.
/// A class's auto and per-region auto, and its oracle's PSNR.
type RegionCompare = (String, table::Summary, table::Summary, f64);

fn regions_summary(md: &mut String, rows: &[Row], per_region: &[RegionCompare]) {
    if per_region.is_empty() {
        return;
    }
    let mean = |f: &dyn Fn(&RegionCompare) -> f64| table::mean(per_region.iter().map(f));
    let (pa, pr, po) = (mean(&|c| c.1.psnr), mean(&|c| c.2.psnr), mean(&|c| c.3));
    let (ca, cr) = (mean(&|c| c.1.p50_1t_ms), mean(&|c| c.2.p50_1t_ms));
    // Tiles per method over every recording, from the rows' labels (`m xN`).
    let mut tiles: BTreeMap<String, usize> = BTreeMap::new();
    for r in rows
        .iter()
        .filter(|r| r.method == REGIONS_NAME && r.set != "real")
    {
        let inside = r.label.split_once(" [").map_or("", |x| x.1);
        let words: Vec<&str> = inside.trim_end_matches(']').split_whitespace().collect();
        for pair in words.windows(2) {
            if let Some(n) = pair[1]
                .strip_prefix('x')
                .and_then(|n| n.parse::<usize>().ok())
                && pair[0] != "late"
            {
                *tiles.entry(pair[0].to_string()).or_default() += n;
            }
        }
    }
    let total: usize = tiles.values().sum();
    let mut shares: Vec<(String, usize)> = tiles.into_iter().collect();
    shares.sort_by_key(|s| std::cmp::Reverse(s.1));
    let shares: Vec<String> = shares
        .iter()
        .map(|(m, n)| format!("{m} {:.1}%", 100.0 * *n as f64 / total.max(1) as f64))
        .collect();
    let mut by_gain: Vec<(f64, &str, f64, f64)> = per_region
        .iter()
        .map(|c| {
            (
                c.2.psnr - c.1.psnr,
                c.0.as_str(),
                c.1.p50_1t_ms,
                c.2.p50_1t_ms,
            )
        })
        .filter(|c| c.0.is_finite())
        .collect();
    by_gain.sort_by(|a, b| b.0.total_cmp(&a.0));
    let show = |c: &[(f64, &str, f64, f64)]| {
        c.iter()
            .map(|(g, n, ma, mr)| format!("{n} {g:+.2} dB ({ma:.1} -> {mr:.1} ms)"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let k = by_gain.len().min(3);
    let _ = writeln!(
        md,
        "Per region (`{REGIONS_NAME}`: the infer node's stage with `--regions {}x{}`, one thread, \
         its own measure of each frame): {pr:.2} dB, {:.1}% of the oracle (auto {pa:.2} dB, \
         {:.1}%), at {cr:.2} ms a frame against auto's {ca:.2} ms ({:.2}x). Tiles: {}. Most \
         gained: {}; most lost: {}.\n",
        REGIONS_TILE.0,
        REGIONS_TILE.1,
        100.0 * pr / po,
        100.0 * pa / po,
        cr / ca,
        shares.join(", "),
        show(&by_gain[..k]),
        show(&by_gain[by_gain.len() - k..]),
    );
}
