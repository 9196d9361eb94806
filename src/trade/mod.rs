//! `neuspike bench`: the speed-accuracy trade of every reconstruction method, measured over the
//! scenes a user meets.
//!
//! The grid ([`grid`]) is the paper's 5 light scales x 5 speeds at full sensor size (400x250,
//! both cameras) plus six extreme corners, each seen through several textures never used in
//! training. Every method ([`run::methods`]) runs each recording as a graph would run it
//! ([`run::pass`]): align's windows every 20 planes, the represent stage computing only what the
//! method reads (a network's inputs made by the infer stage of the window itself, as in the live
//! graph and in `auto`), the infer stage's `Reconstructor`; a window's cost is its representation plus
//! its reconstruction, timed on 1 and on 2 threads. Four frames a recording are scored against
//! the truth (PSNR, PSNR after gain, SSIM, 2D entropy, as the sink computes them).
//!
//! Output, in `--out`: `bench.csv` (one row per class x texture x method; a run skips the rows
//! already there, so an interrupted run resumes), `summary.md` (per scene group, the methods'
//! figures, the Pareto front and the method to choose; a light x speed map of the winners; the
//! corners; the physics fusion's standing; real recordings scored without truth), and plots:
//! `pareto.png` (PSNR against cost per group, the front drawn) and `winners.png`.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use eyre::{WrapErr, eyre};
use ndarray::ArrayView2;
use neuspike_metrics as metrics;

pub mod auto;
pub mod grid;
pub mod plot;
pub mod run;
pub mod table;

use grid::{SceneClass, TextureSet};
use run::{Cache, MethodSpec, Recording};
use table::Row;

/// The trade bench's arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct BenchOptions {
    /// Output folder: bench.csv (kept and extended across runs), summary.md, plots.
    #[arg(long, default_value = "out/bench")]
    pub out: PathBuf,
    /// The small grid: 3 light scales x 3 speeds and the corners, 2 textures (under 10 minutes
    /// on 2 cores).
    #[arg(long)]
    pub quick: bool,
    /// Textures per scene class (default 4, or 2 with --quick).
    #[arg(long)]
    pub textures: Option<usize>,
    /// Which textures: held-out (never used in training) or train (to fit a policy on).
    #[arg(long, value_enum, default_value = "held-out")]
    pub set: TextureSet,
    /// Only these methods (names as in the tables, comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Only these scene classes (names as in the tables, comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub classes: Vec<String>,
    /// The spike camera's noise (a profile and per-term overrides, as `spike-source` takes them):
    /// how the methods fare when the camera differs from the one the networks were trained on.
    /// Give each setting its own `--out`.
    #[command(flatten)]
    pub noise: neuspike_spike_camera::NoiseArgs,
    /// The event camera as a sensor of its own, as in a real rig: a DAVIS346 (346x260) seeing
    /// the scene through a homography (1.16 spike pixels a pixel, turned 0.5 degree), its clock
    /// 3 ms ahead; its events reach the methods through align's mapping onto the spike grid and
    /// clock (what `--homography` and `--event-offset-ns` do in a graph). Give it its own
    /// `--out`.
    #[arg(long)]
    pub rig: bool,
    /// The folder of the networks (`*.onnx`).
    #[arg(long, default_value = "models")]
    pub models: PathBuf,
    /// A real spike recording (PKU .dat, 400x250, 20 kHz) to score without truth (2D entropy and
    /// cost) with the spike-only methods. Repeatable.
    #[arg(long)]
    pub real: Vec<PathBuf>,
    /// Write only the summary and plots from bench.csv, running nothing.
    #[arg(long)]
    pub report_only: bool,
    /// The policy of the `auto` method, run beside the others (default: models/policy.yml
    /// when it exists; `none` for no auto).
    #[arg(long)]
    pub policy: Option<PathBuf>,
    /// After the run, fit a policy from the CSV's rows of `--set train` and write it here.
    #[arg(long)]
    pub fit_policy: Option<PathBuf>,
    /// Fitting: the price of compute, decibels of PSNR a method must gain per extra millisecond
    /// of a frame (one thread) to be chosen; 0 takes the most accurate method whatever it costs.
    #[arg(long, default_value_t = 0.04)]
    pub db_per_ms: f64,
    /// Budget mode's deadline, ms: with a policy, the infer node's `auto` stage runs each
    /// recording under it on `--budget-threads` threads (rows `auto-<X>ms`, `auto-<X>ms-2t` on
    /// two).
    #[arg(long, default_value_t = 5.0)]
    pub budget_ms: f64,
    /// Threads budget mode's stage runs its networks on (the infer node's `--threads`); its
    /// cost priors are the policy's figures for as many threads.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub budget_threads: u16,
    /// Measure these methods again: their rows are removed from bench.csv first (e.g. `auto`
    /// after fitting a new policy).
    #[arg(long, value_delimiter = ',')]
    pub redo: Vec<String>,
}

/// What a run did.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRun {
    /// Rows written by this run.
    pub new_rows: usize,
    /// Rows in the CSV now.
    pub rows: usize,
    /// (Method, recording) pairs skipped because the CSV had them.
    pub skipped: usize,
    /// The output folder.
    pub out: PathBuf,
}

/// Scores one pass's frames against the truth: the row's accuracy fields.
fn score(
    row: &mut Row,
    frames: &[ndarray::Array2<f32>],
    truth: Option<&Vec<ndarray::Array2<f32>>>,
) {
    row.frames = frames.len();
    row.finite = frames.iter().all(|f| f.iter().all(|v| v.is_finite()));
    row.entropy = table::mean(frames.iter().map(|f| metrics::entropy_2d(f.view())));
    let Some(truth) = truth else {
        return;
    };
    let pairs = || frames.iter().zip(truth).map(|(f, g)| (f.view(), g.view()));
    let psnr: Vec<f64> = pairs().map(|(f, g)| metrics::psnr(f, g)).collect();
    row.exact = psnr.iter().filter(|p| p.is_infinite()).count();
    row.psnr = table::mean(psnr);
    row.psnr_gain = table::mean(pairs().map(|(f, g)| metrics::psnr_after_gain(f, g)));
    row.ssim = table::mean(pairs().map(|(f, g): (ArrayView2<f32>, _)| metrics::ssim(f, g)));
}

/// One method on one recording: a pass on 1 thread (scored) and one on 2 (timed); the row, and
/// what `auto` takes from the passes.
fn measure(
    spec: &MethodSpec,
    rec: &Recording,
    template: &Row,
    cache: &mut Cache,
) -> eyre::Result<(Row, auto::Kept)> {
    let one = run::pass(spec, rec, 1, cache)?;
    let two = run::pass(spec, rec, 2, cache)?;
    let mut row = Row {
        method: spec.name.clone(),
        p50_1t_ms: table::percentile(&one.times_ms, 50.0),
        p99_1t_ms: table::percentile(&one.times_ms, 99.0),
        p50_2t_ms: table::percentile(&two.times_ms, 50.0),
        p99_2t_ms: table::percentile(&two.times_ms, 99.0),
        windows: one.times_ms.len(),
        peak_mib: if crate::memory::counting() {
            one.peak_bytes.max(two.peak_bytes) as f64 / (1024.0 * 1024.0)
        } else {
            f64::NAN
        },
        ..template.clone()
    };
    score(&mut row, &one.frames, rec.truth.as_ref());
    let kept = auto::Kept {
        stateful: spec.stateful(),
        p50_ms: [row.p50_1t_ms, row.p50_2t_ms],
        scored_ms: [one.scored_ms, two.scored_ms],
        peak_bytes: one.peak_bytes.max(two.peak_bytes),
        frames: one.frames,
    };
    Ok((row, kept))
}

/// Runs the bench: every (class, texture, method) not yet in `bench.csv`, then the summary and
/// plots from the whole CSV.
///
/// # Errors
/// Bad options, a CSV from another version, a network that does not load, a method that fails,
/// or an output that cannot be written. Rows measured before the failure stay in the CSV.
pub fn run(opts: &BenchOptions, progress: bool) -> eyre::Result<BenchRun> {
    let opts = &BenchOptions {
        models: crate::models::or_shipped(&opts.models),
        ..opts.clone()
    };
    let started = Instant::now();
    std::fs::create_dir_all(&opts.out)
        .wrap_err_with(|| format!("cannot create {}", opts.out.display()))?;
    let csv_path = opts.out.join("bench.csv");
    let mut rows = table::read(&csv_path)?;
    if !opts.redo.is_empty() {
        let n = rows.len();
        rows.retain(|r| !opts.redo.contains(&r.method));
        if rows.len() != n {
            let mut text = format!("{}\n", table::HEADER);
            for r in &rows {
                let _ = writeln!(text, "{}", r.to_csv());
            }
            neuspike_formats::atomic::write(&csv_path, text)
                .wrap_err_with(|| format!("cannot write {}", csv_path.display()))?;
        }
    }
    let before = rows.len();
    let mut skipped = 0;
    let policy_used;
    if opts.report_only {
        // The summary names the policy's provenance.
        let path = opts
            .policy
            .clone()
            .unwrap_or_else(|| opts.models.join(auto::DEFAULT_POLICY));
        policy_used = neuspike_reconstruction::policy::Policy::read(&path).ok();
    } else {
        let mut methods = run::methods(&opts.models)?;
        let installed = methods.clone();
        let wants_auto = opts.methods.is_empty()
            || opts
                .methods
                .iter()
                .any(|m| m == auto::NAME || m == auto::REGIONS_NAME);
        let loaded = if wants_auto {
            auto::policy(opts, &methods)?
        } else {
            None
        };
        let policy = loaded.as_ref().map(|(_, p)| p.clone());
        policy_used = policy.clone();
        // Budget mode runs the infer node's own stage, loaded once (its networks planned once).
        // Its cost priors are for the threads its networks run on.
        neuspike_reconstruction::learned::set_threads(usize::from(opts.budget_threads));
        let mut stage = match &loaded {
            Some((path, _)) => Some(
                neuspike_reconstruction::auto::Auto::new(
                    path,
                    &opts.models,
                    Some(opts.budget_ms),
                    None,
                    neuspike_reconstruction::learned::ConvPath::Auto,
                )
                .map_err(|e| eyre!("--policy: {e}"))?,
            ),
            None => None,
        };
        let budget_name = auto::budget_name(opts.budget_ms, usize::from(opts.budget_threads));
        neuspike_reconstruction::learned::set_threads(1);
        // Per-region auto: the same stage, choosing per tile.
        let mut regions = match &loaded {
            Some((path, _)) => Some(
                neuspike_reconstruction::auto::Auto::new(
                    path,
                    &opts.models,
                    None,
                    None,
                    neuspike_reconstruction::learned::ConvPath::Auto,
                )
                .and_then(|a| a.with_regions(auto::REGIONS_TILE.0, auto::REGIONS_TILE.1))
                .map_err(|e| eyre!("--policy: {e}"))?,
            ),
            None => None,
        };
        if !opts.methods.is_empty() {
            for m in &opts.methods {
                if m != auto::NAME
                    && m != auto::REGIONS_NAME
                    && !methods.iter().any(|s| s.name == *m)
                {
                    return Err(eyre!(
                        "--methods {m}: no such method (there are {}, auto and auto-regions)",
                        methods
                            .iter()
                            .map(|s| s.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ));
                }
            }
            methods.retain(|s| opts.methods.contains(&s.name));
        }
        let mut classes = grid::classes(opts.quick);
        if !opts.classes.is_empty() {
            let all = grid::classes(false);
            for c in &opts.classes {
                if !all.iter().any(|s| s.name == *c) {
                    return Err(eyre!(
                        "--classes {c}: no such scene class (there are {})",
                        all.iter()
                            .map(|s| s.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ));
                }
            }
            classes = all
                .into_iter()
                .filter(|s| opts.classes.contains(&s.name))
                .collect();
        }
        let textures = opts.textures.unwrap_or(if opts.quick { 2 } else { 4 });
        if textures == 0 {
            return Err(eyre!("--textures 0: at least one texture is needed"));
        }
        let have: std::collections::BTreeSet<_> = rows.iter().map(Row::key).collect();
        let mut csv = open_csv(&csv_path, before == 0)?;
        let units: Vec<(SceneClass, usize)> = classes
            .iter()
            .flat_map(|c| (0..textures).map(move |t| (c.clone(), t)))
            .collect();
        let bar = progress.then(|| {
            let b =
                indicatif::ProgressBar::new((units.len() * methods.len() + opts.real.len()) as u64);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:30}] {pos}/{len} {msg} (eta {eta})",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        });
        let mut cache = Cache::default();
        let set = opts.set.as_str().to_string();
        for (class, t) in &units {
            let todo: Vec<&MethodSpec> = methods
                .iter()
                .filter(|m| !have.contains(&(set.clone(), class.name.clone(), *t, m.name.clone())))
                .collect();
            skipped += methods.len() - todo.len();
            if let Some(b) = &bar {
                b.inc((methods.len() - todo.len()) as u64);
            }
            let auto_missing = policy.is_some()
                && !have.contains(&(set.clone(), class.name.clone(), *t, auto::NAME.to_string()));
            let budget_missing = stage.is_some()
                && !have.contains(&(set.clone(), class.name.clone(), *t, budget_name.clone()));
            let regions_missing = regions.is_some()
                && !have.contains(&(
                    set.clone(),
                    class.name.clone(),
                    *t,
                    auto::REGIONS_NAME.to_string(),
                ));
            if todo.is_empty() && !auto_missing && !budget_missing && !regions_missing {
                continue;
            }
            if let Some(b) = &bar {
                b.set_message(format!("{} texture {t}: simulating", class.name));
            }
            let (rec, label) = run::simulate(class, opts.set, *t, &opts.noise, opts.rig)
                .wrap_err_with(|| format!("bench: {} texture {t}", class.name))?;
            let stats = run::window_stats(&rec)?;
            let template = with_stats(
                Row {
                    set: set.clone(),
                    class: class.name.clone(),
                    group: class.group(),
                    light: class.light,
                    speed_px_s: class.speed_px_s,
                    texture: *t,
                    label,
                    ..empty_row()
                },
                &stats,
            );
            // `auto` needs the frames of every method its policy names, rows or not.
            let auto_todo = policy.is_some()
                && !have.contains(&(set.clone(), class.name.clone(), *t, auto::NAME.to_string()));
            let mut kept = std::collections::BTreeMap::new();
            for spec in &installed {
                let row_todo = todo.iter().any(|m| m.name == spec.name);
                let for_auto = auto_todo
                    && policy
                        .as_ref()
                        .is_some_and(|p| p.methods().contains(&spec.name.as_str()));
                if !row_todo && !for_auto {
                    continue;
                }
                if let Some(b) = &bar {
                    b.set_message(format!("{} texture {t}: {}", class.name, spec.name));
                }
                let (row, k) = measure(spec, &rec, &template, &mut cache)
                    .wrap_err_with(|| format!("bench: {} texture {t}", class.name))?;
                if row_todo {
                    write_row(&mut csv, &csv_path, &row)?;
                    rows.push(row);
                    if let Some(b) = &bar {
                        b.inc(1);
                    }
                }
                if for_auto {
                    kept.insert(spec.name.clone(), k);
                }
            }
            if let (true, Some(p)) = (auto_todo, &policy) {
                let row = auto::row(p, &rec, &stats, &kept, &template)
                    .wrap_err_with(|| format!("bench: {} texture {t}", class.name))?;
                write_row(&mut csv, &csv_path, &row)?;
                rows.push(row);
            }
            if let (true, Some(s)) = (budget_missing, stage.as_mut()) {
                if let Some(b) = &bar {
                    b.set_message(format!("{} texture {t}: {budget_name}", class.name));
                }
                let budget = (opts.budget_ms, usize::from(opts.budget_threads));
                let (row, _) = auto::budget_row(s, budget, &rec, &template)
                    .wrap_err_with(|| format!("bench: {} texture {t}", class.name))?;
                write_row(&mut csv, &csv_path, &row)?;
                rows.push(row);
            }
            if let (true, Some(s)) = (regions_missing, regions.as_mut()) {
                if let Some(b) = &bar {
                    b.set_message(format!(
                        "{} texture {t}: {}",
                        class.name,
                        auto::REGIONS_NAME
                    ));
                }
                let (row, _) = auto::stage_row(s, auto::REGIONS_NAME, 1, &rec, &template)
                    .wrap_err_with(|| format!("bench: {} texture {t}", class.name))?;
                write_row(&mut csv, &csv_path, &row)?;
                rows.push(row);
            }
        }
        for path in &opts.real {
            let name = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let class = format!("real:{name}");
            let rec = run::real(path)?;
            let template = with_stats(
                Row {
                    set: "real".into(),
                    class: class.clone(),
                    group: "real".into(),
                    label: name,
                    ..empty_row()
                },
                &run::window_stats(&rec)?,
            );
            for spec in methods.iter().filter(|m| rec.fits(m)) {
                if have.contains(&("real".into(), class.clone(), 0, spec.name.clone())) {
                    skipped += 1;
                    continue;
                }
                let (row, _) = measure(spec, &rec, &template, &mut cache)
                    .wrap_err_with(|| format!("bench: {}", path.display()))?;
                write_row(&mut csv, &csv_path, &row)?;
                rows.push(row);
            }
            if let Some(b) = &bar {
                b.inc(1);
            }
        }
        if let Some(b) = bar {
            b.finish_and_clear();
        }
    }
    let new_rows = rows.len() - before;
    if let Some(out) = &opts.fit_policy {
        let p = auto::fit(&rows, opts, &csv_path)?;
        neuspike_formats::atomic::write(out, p.to_yaml())
            .wrap_err_with(|| format!("--fit-policy {}: cannot write", out.display()))?;
    }
    let mut md = summary(&rows, opts, started.elapsed().as_secs_f64(), new_rows);
    auto::summary(&mut md, &rows, policy_used.as_ref());
    let md_path = opts.out.join("summary.md");
    neuspike_formats::atomic::write(&md_path, md)
        .wrap_err_with(|| format!("cannot write {}", md_path.display()))?;
    plot::pareto(&rows, &opts.out.join("pareto.png"))?;
    plot::winners(&rows, &opts.out.join("winners.png"))?;
    Ok(BenchRun {
        new_rows,
        rows: rows.len(),
        skipped,
        out: opts.out.clone(),
    })
}

fn write_row(
    csv: &mut std::io::BufWriter<std::fs::File>,
    path: &std::path::Path,
    row: &Row,
) -> eyre::Result<()> {
    writeln!(csv, "{}", row.to_csv())
        .and_then(|()| csv.flush())
        .wrap_err_with(|| format!("cannot write {}", path.display()))
}

fn open_csv(
    path: &std::path::Path,
    fresh: bool,
) -> eyre::Result<std::io::BufWriter<std::fs::File>> {
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .wrap_err_with(|| format!("cannot open {}", path.display()))?;
    let mut w = std::io::BufWriter::new(file);
    if fresh {
        writeln!(w, "{}", table::HEADER)
            .and_then(|()| w.flush())
            .wrap_err_with(|| format!("cannot write {}", path.display()))?;
    }
    Ok(w)
}

fn empty_row() -> Row {
    Row {
        set: String::new(),
        class: String::new(),
        group: String::new(),
        light: f64::NAN,
        speed_px_s: f64::NAN,
        texture: 0,
        label: String::new(),
        method: String::new(),
        frames: 0,
        exact: 0,
        finite: true,
        psnr: f64::NAN,
        psnr_gain: f64::NAN,
        ssim: f64::NAN,
        entropy: f64::NAN,
        p50_1t_ms: f64::NAN,
        p99_1t_ms: f64::NAN,
        p50_2t_ms: f64::NAN,
        p99_2t_ms: f64::NAN,
        windows: 0,
        peak_mib: f64::NAN,
        rate: f64::NAN,
        event_rate: f64::NAN,
        change: f64::NAN,
        spread_decades: f64::NAN,
        edge: f64::NAN,
    }
}

/// The row template's statistics: the mean over the scored windows.
fn with_stats(mut row: Row, stats: &[(neuspike_representations::WindowStats, f64)]) -> Row {
    let m = |f: fn(&neuspike_representations::WindowStats) -> f64| {
        table::mean(stats.iter().map(|(s, _)| f(s)))
    };
    row.rate = m(|s| s.rate);
    row.event_rate = m(|s| s.event_rate);
    row.change = m(|s| s.change);
    row.spread_decades = m(|s| s.spread_decades);
    row.edge = m(|s| s.edge);
    row
}

/// The tolerance of "as good as the best": a method within this of the best mean PSNR counts as
/// a choice, and the cheapest such is recommended.
pub const TOLERANCE_DB: f64 = 0.5;

/// The markdown summary of every row.
fn summary(rows: &[Row], opts: &BenchOptions, seconds: f64, new_rows: usize) -> String {
    let mut md = String::new();
    let with_auto: Vec<Row> = rows.iter().filter(|r| r.set != "real").cloned().collect();
    // The oracle and the choices are among the methods themselves, not `auto`.
    let scored: Vec<Row> = with_auto
        .iter()
        .filter(|r| !auto::is_auto(&r.method))
        .cloned()
        .collect();
    let sets: std::collections::BTreeSet<&str> = scored.iter().map(|r| r.set.as_str()).collect();
    let textures: std::collections::BTreeSet<usize> = scored.iter().map(|r| r.texture).collect();
    let _ = writeln!(
        md,
        "# The speed-accuracy trade\n\n`neuspike bench{}` ({} rows, {new_rows} new in {seconds:.0} s). \
         Textures: {} a scene class, from the {} set{}. Every scene is 400x250 with both cameras \
         (the DVS at the spike camera's size), 488 planes at 20 kHz; windows every 20 planes; \
         frames scored at planes 300, 320, 340 and 360 against the scene's luminance in [0, 1]. \
         Cost: representation plus reconstruction of one window, as the graph pays it \
         (milliseconds, median and 99th percentile over the windows run). PSNR is plain (not after \
         gain) unless a column says otherwise.\n",
        if opts.quick { " --quick" } else { "" },
        rows.len(),
        textures.len(),
        sets.iter().copied().collect::<Vec<_>>().join(", "),
        if sets.len() == 1 { "" } else { "s" },
    );
    let groups = table::by(&scored, |r| r.group.clone());
    let summarised = |methods: &Vec<(String, Vec<&Row>)>| -> Vec<(String, table::Summary)> {
        methods
            .iter()
            .map(|(m, rs)| (m.clone(), table::summarise(rs)))
            .collect()
    };
    let _ = writeln!(
        md,
        "## Which method for which scene\n\nThe best mean PSNR, and the cheapest method within \
         {TOLERANCE_DB} dB of it (the one to choose).\n\n| scene group | best | PSNR dB | choose | PSNR dB | ms, 1 thread | cost vs best |\n|---|---|---|---|---|---|---|"
    );
    for (g, methods) in &groups {
        let per = summarised(methods);
        if let Some((best, pick)) = table::choice(&per, TOLERANCE_DB) {
            let get = |n: &str| {
                per.iter()
                    .find(|(m, _)| m == n)
                    .map(|(_, s)| s.clone())
                    .unwrap_or_default()
            };
            let (b, p) = (get(&best), get(&pick));
            let _ = writeln!(
                md,
                "| {g} | {best} | {} | {pick} | {} | {} | {} |",
                table::fmt(b.psnr, 2),
                table::fmt(p.psnr, 2),
                table::fmt(p.p50_1t_ms, 2),
                if b.p50_1t_ms > 0.0 {
                    format!("{:.3}x", p.p50_1t_ms / b.p50_1t_ms)
                } else {
                    "-".into()
                },
            );
        }
    }
    let _ = writeln!(md, "\n## Light x speed: the best method (PSNR dB)\n");
    let grid_rows: Vec<Row> = scored
        .iter()
        .filter(|r| r.class.starts_with("light"))
        .cloned()
        .collect();
    let cells = table::by(&grid_rows, |r| r.class.clone());
    let mut lights: Vec<f64> = scored
        .iter()
        .filter(|r| r.class.starts_with("light"))
        .map(|r| r.light)
        .collect();
    let mut speeds: Vec<f64> = scored
        .iter()
        .filter(|r| r.class.starts_with("light"))
        .map(|r| r.speed_px_s)
        .collect();
    for v in [&mut lights, &mut speeds] {
        v.sort_by(f64::total_cmp);
        v.dedup();
    }
    let _ = writeln!(
        md,
        "| light \\ speed px/s | {} |\n|---|{}",
        speeds
            .iter()
            .map(|s| format!("{s}"))
            .collect::<Vec<_>>()
            .join(" | "),
        "---|".repeat(speeds.len())
    );
    for l in &lights {
        let _ = write!(md, "| {l} |");
        for s in &speeds {
            let name = SceneClass::cell(*l, *s).name;
            let cell = cells.get(&name).map(summarised);
            let text = cell
                .and_then(|per| {
                    table::choice(&per, 0.0).and_then(|(best, _)| {
                        per.iter()
                            .find(|(m, _)| *m == best)
                            .map(|(_, s)| format!("{best} {:.1}", s.psnr))
                    })
                })
                .unwrap_or_else(|| "-".into());
            let _ = write!(md, " {text} |");
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md, "\n## Every method, per scene group\n");
    for (g, methods) in &table::by(&with_auto, |r| r.group.clone()) {
        let per = summarised(methods);
        let front = table::pareto(
            &per.iter()
                .map(|(m, s)| (m.clone(), s.p50_1t_ms, s.psnr))
                .collect::<Vec<_>>(),
        );
        let _ = writeln!(
            md,
            "### {g}\n\nPareto front (cost, PSNR): {}.\n",
            front
                .iter()
                .map(|f| f.0.as_str())
                .collect::<Vec<_>>()
                .join(" -> ")
        );
        table::method_table(&mut md, &per);
        let _ = writeln!(md);
    }
    let _ = writeln!(md, "## The extreme corners\n");
    for c in grid::Corner::ALL {
        let Some(methods) = groups.get(c.as_str()) else {
            continue;
        };
        let per = summarised(methods);
        let finite = per.iter().all(|(_, s)| s.finite);
        let best = per
            .iter()
            .filter(|(_, s)| s.psnr.is_finite())
            .map(|(_, s)| s.psnr)
            .fold(f64::NAN, f64::max);
        let Some((b, pick)) = table::choice(&per, TOLERANCE_DB) else {
            continue;
        };
        let why = match c {
            grid::Corner::NoLight => {
                "nothing reaches the sensor: no method recovers the scene, so the cheapest is the answer"
            }
            grid::Corner::Saturated => {
                "the spike camera fires every tick wherever the scene is brighter than 1/4 of full scale: rates carry no texture there, and events see the motion"
            }
            grid::Corner::Hdr => {
                "the dim half fires rarely (long intervals): methods that wait for spikes or read events recover it, short windows do not"
            }
            grid::Corner::EventFlood => {
                "a flood of events at a low threshold: event methods pay per event, spike methods do not"
            }
            grid::Corner::StaticDark => {
                "nothing moves and little light comes in: the longest window averages the most spikes without blur"
            }
            grid::Corner::StaticToFast => {
                "long windows blur once the motion starts; short windows are noisy while still"
            }
        };
        let _ = writeln!(
            md,
            "- **{}**: every frame finite: {}. Best {b} ({:.2} dB); choose **{pick}**. Why: {why}.",
            c.as_str(),
            if finite { "yes" } else { "NO" },
            best
        );
    }
    let _ = writeln!(
        md,
        "\n## The physics fusion\n\n`fusion` re-anchors on each window's ISI (Eq. 5-7); `fusion-tfp` \
         keeps a TFP whose window the pixel's events set (rescaled and forgotten as they say the \
         luminance changed) and carries it with the events. Per scene class, whether each beats \
         TFI and TFP over 33 planes, is the best classical method (no network), or the best of all:\n\n\
         | method | beats TFI | beats TFP-33 | best classical | best of all | classes where it is the best classical method |\n|---|---|---|---|---|---|"
    );
    let by_class = table::by(&scored, |r| r.class.clone());
    for f in ["fusion", "fusion-tfp"] {
        let (mut tfi, mut tfp, mut classical, mut all, mut n) = (0, 0, 0, 0, 0);
        let mut wins = Vec::new();
        for (class, methods) in &by_class {
            let per = summarised(methods);
            let get = |m: &str| per.iter().find(|(x, _)| x == m).map(|(_, s)| s.psnr);
            let Some(me) = get(f) else { continue };
            n += 1;
            tfi += usize::from(get("tfi").is_some_and(|v| me > v));
            tfp += usize::from(get("tfp-33").is_some_and(|v| me > v));
            let best_classical = per
                .iter()
                .filter(|(m, _)| !m.starts_with("neuspike-"))
                .map(|(_, s)| s.psnr)
                .filter(|v| v.is_finite())
                .fold(f64::MIN, f64::max);
            if me >= best_classical {
                classical += 1;
                wins.push(class.clone());
            }
            all += usize::from(table::choice(&per, 0.0).is_some_and(|(b, _)| b == f));
        }
        if n > 0 {
            let _ = writeln!(
                md,
                "| {f} | {tfi} of {n} | {tfp} of {n} | {classical} of {n} | {all} of {n} | {} |",
                if wins.is_empty() {
                    "-".to_string()
                } else {
                    wins.join(", ")
                }
            );
        }
    }
    let _ = writeln!(md);
    let real: Vec<Row> = rows.iter().filter(|r| r.set == "real").cloned().collect();
    if !real.is_empty() {
        let _ = writeln!(
            md,
            "## Real recordings (no ground truth)\n\n2D entropy and cost of the spike-only methods \
             (a gain maps the mean firing rate to luminance 0.5).\n"
        );
        for (class, methods) in table::by(&real, |r| r.class.clone()) {
            let _ = writeln!(md, "### {class}\n");
            table::method_table(&mut md, &summarised(&methods));
            let _ = writeln!(md);
        }
    }
    md
}
