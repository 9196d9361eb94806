//! The bench's rows (one per scene class x texture x method), their CSV, and the summaries drawn
//! from them.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use eyre::{WrapErr, bail};

/// The CSV's header.
pub const HEADER: &str = "set,class,group,light,speed_px_s,texture,label,method,frames,exact,\
finite,psnr,psnr_gain,ssim,entropy,p50_1t_ms,p99_1t_ms,p50_2t_ms,p99_2t_ms,windows,peak_mib,rate,event_rate,change,spread_decades,edge";

/// One row: a method on one texture of one scene class. Metrics are means over the scored
/// frames; `NaN` (an empty CSV field) where there is no truth, or, for PSNR, where every frame
/// was exact.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Texture set (`held-out`, `train`), or `real` for a recording.
    pub set: String,
    /// Scene class.
    pub class: String,
    /// Its group (`dark slow`, a corner's name, `real`).
    pub group: String,
    /// Light scale (NaN for a recording).
    pub light: f64,
    /// Speed, px/s (NaN for a recording).
    pub speed_px_s: f64,
    /// Texture index within the set.
    pub texture: usize,
    /// Texture label (`noise:1234`) or the recording's file name.
    pub label: String,
    /// Method name.
    pub method: String,
    /// Frames scored.
    pub frames: usize,
    /// Frames equal to the truth (PSNR infinite; left out of the PSNR mean).
    pub exact: usize,
    /// Whether every pixel of every frame was finite.
    pub finite: bool,
    /// PSNR, dB.
    pub psnr: f64,
    /// PSNR after the least-squares gain, dB.
    pub psnr_gain: f64,
    /// SSIM.
    pub ssim: f64,
    /// 2D entropy, bits.
    pub entropy: f64,
    /// Median milliseconds a window, one thread.
    pub p50_1t_ms: f64,
    /// 99th percentile, one thread.
    pub p99_1t_ms: f64,
    /// Median, two threads.
    pub p50_2t_ms: f64,
    /// 99th percentile, two threads.
    pub p99_2t_ms: f64,
    /// Windows timed per thread count.
    pub windows: usize,
    /// Peak heap, MiB (NaN where not measured).
    pub peak_mib: f64,
    /// The recording's window statistics (`neuspike_representations::window_stats`, mean over the
    /// scored windows): spikes per pixel per plane.
    pub rate: f64,
    /// Events per pixel per plane.
    pub event_rate: f64,
    /// Change between the windows' halves.
    pub change: f64,
    /// Spread of block firing rates, decades.
    pub spread_decades: f64,
    /// Texture: relative difference of adjacent cells' spike counts.
    pub edge: f64,
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else if v.is_nan() {
        String::new()
    } else {
        v.to_string()
    }
}

impl Row {
    /// The row as a CSV line (no newline).
    pub fn to_csv(&self) -> String {
        [
            self.set.clone(),
            self.class.clone(),
            self.group.clone(),
            num(self.light),
            num(self.speed_px_s),
            self.texture.to_string(),
            self.label.clone(),
            self.method.clone(),
            self.frames.to_string(),
            self.exact.to_string(),
            u8::from(self.finite).to_string(),
            num(self.psnr),
            num(self.psnr_gain),
            num(self.ssim),
            num(self.entropy),
            num(self.p50_1t_ms),
            num(self.p99_1t_ms),
            num(self.p50_2t_ms),
            num(self.p99_2t_ms),
            self.windows.to_string(),
            num(self.peak_mib),
            format!("{:.6}", self.rate),
            format!("{:.6}", self.event_rate),
            num(self.change),
            num(self.spread_decades),
            num(self.edge),
        ]
        .join(",")
    }

    /// Parses a CSV line; the error names the field and its value.
    pub fn from_csv(line: &str) -> Result<Row, String> {
        let f: Vec<&str> = line.split(',').collect();
        let names: Vec<&str> = HEADER.split(',').collect();
        if f.len() != names.len() {
            return Err(format!("{} fields, expected {}", f.len(), names.len()));
        }
        let float = |i: usize| -> Result<f64, String> {
            if f[i].is_empty() {
                return Ok(f64::NAN);
            }
            f[i].parse()
                .map_err(|_| format!("field {} = {:?}: not a number", names[i], f[i]))
        };
        let int = |i: usize| -> Result<usize, String> {
            f[i].parse()
                .map_err(|_| format!("field {} = {:?}: not a count", names[i], f[i]))
        };
        Ok(Row {
            set: f[0].to_string(),
            class: f[1].to_string(),
            group: f[2].to_string(),
            light: float(3)?,
            speed_px_s: float(4)?,
            texture: int(5)?,
            label: f[6].to_string(),
            method: f[7].to_string(),
            frames: int(8)?,
            exact: int(9)?,
            finite: match f[10] {
                "1" => true,
                "0" => false,
                v => return Err(format!("field finite = {v:?}: not 0 or 1")),
            },
            psnr: float(11)?,
            psnr_gain: float(12)?,
            ssim: float(13)?,
            entropy: float(14)?,
            p50_1t_ms: float(15)?,
            p99_1t_ms: float(16)?,
            p50_2t_ms: float(17)?,
            p99_2t_ms: float(18)?,
            windows: int(19)?,
            peak_mib: float(20)?,
            rate: float(21)?,
            event_rate: float(22)?,
            change: float(23)?,
            spread_decades: float(24)?,
            edge: float(25)?,
        })
    }

    /// What identifies a row: a run skips what the CSV holds already.
    pub fn key(&self) -> (String, String, usize, String) {
        (
            self.set.clone(),
            self.class.clone(),
            self.texture,
            self.method.clone(),
        )
    }
}

/// Reads the rows of a CSV the bench wrote (none if the file does not exist).
///
/// # Errors
/// The file cannot be read, its header is not the bench's, or a line does not parse (named with
/// its number).
pub fn read(path: &Path) -> eyre::Result<Vec<Row>> {
    if !path.exists() {
        return Ok(Vec::new());
    }
    let text = std::fs::read_to_string(path)
        .wrap_err_with(|| format!("cannot read {}", path.display()))?;
    let mut lines = text.lines();
    match lines.next() {
        Some(h) if h == HEADER => {}
        Some(h) => bail!(
            "{}: header {h:?} is not the bench's (another version wrote it: move it away)",
            path.display()
        ),
        None => return Ok(Vec::new()),
    }
    lines
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            Row::from_csv(l).map_err(|e| eyre::eyre!("{} line {}: {e}", path.display(), i + 2))
        })
        .collect()
}

/// Percentile `p` (0..=100) of `xs` by nearest rank; NaN when empty.
pub fn percentile(xs: &[f64], p: f64) -> f64 {
    if xs.is_empty() {
        return f64::NAN;
    }
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * v.len() as f64).ceil().max(1.0) as usize;
    v[rank.min(v.len()) - 1]
}

/// The mean of the finite values; NaN when there are none.
pub fn mean(xs: impl IntoIterator<Item = f64>) -> f64 {
    let (s, n) = xs
        .into_iter()
        .filter(|v| v.is_finite())
        .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if n == 0 { f64::NAN } else { s / n as f64 }
}

/// A method's figures over a set of rows (textures, classes): means, and the spread of PSNR
/// over textures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Summary {
    /// Mean PSNR, dB.
    pub psnr: f64,
    /// Mean PSNR after gain.
    pub psnr_gain: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean 2D entropy.
    pub entropy: f64,
    /// Mean of the rows' median milliseconds, one thread.
    pub p50_1t_ms: f64,
    /// Largest 99th percentile, one thread.
    pub p99_1t_ms: f64,
    /// Mean of the medians, two threads.
    pub p50_2t_ms: f64,
    /// Largest peak heap, MiB.
    pub peak_mib: f64,
    /// Standard deviation over textures of the per-texture mean PSNR (averaged over classes).
    pub spread_db: f64,
    /// Whether every frame was finite.
    pub finite: bool,
    /// Rows.
    pub rows: usize,
}

/// Summarises rows of one method.
pub fn summarise(rows: &[&Row]) -> Summary {
    let max = |f: fn(&Row) -> f64| {
        rows.iter()
            .map(|r| f(r))
            .filter(|v| v.is_finite())
            .fold(f64::NAN, f64::max)
    };
    // Spread: per class, the population standard deviation of its textures' PSNR.
    let mut by_class: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    for r in rows {
        if r.psnr.is_finite() {
            by_class.entry(&r.class).or_default().push(r.psnr);
        }
    }
    let spread = mean(by_class.values().filter(|v| v.len() > 1).map(|v| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
    }));
    Summary {
        psnr: mean(rows.iter().map(|r| r.psnr)),
        psnr_gain: mean(rows.iter().map(|r| r.psnr_gain)),
        ssim: mean(rows.iter().map(|r| r.ssim)),
        entropy: mean(rows.iter().map(|r| r.entropy)),
        p50_1t_ms: mean(rows.iter().map(|r| r.p50_1t_ms)),
        p99_1t_ms: max(|r| r.p99_1t_ms),
        p50_2t_ms: mean(rows.iter().map(|r| r.p50_2t_ms)),
        peak_mib: max(|r| r.peak_mib),
        spread_db: spread,
        finite: rows.iter().all(|r| r.finite),
        rows: rows.len(),
    }
}

/// PSNRs closer than this (dB) are one accuracy on the front: a method that takes another's
/// frames (`auto` choosing TFP) has its mean summed in another order, a few ulps away.
const FRONT_TIE_DB: f64 = 1e-9;

/// The methods on the Pareto front of (cost, PSNR): no other is both cheaper (or as cheap) and
/// more accurate (by more than [`FRONT_TIE_DB`]). `points` are `(name, cost, psnr)`; the front
/// comes sorted by cost.
pub fn pareto(points: &[(String, f64, f64)]) -> Vec<(String, f64, f64)> {
    let mut v: Vec<_> = points
        .iter()
        .filter(|(_, c, p)| c.is_finite() && p.is_finite())
        .cloned()
        .collect();
    v.sort_by(|a, b| a.1.total_cmp(&b.1).then(b.2.total_cmp(&a.2)));
    let mut front: Vec<(String, f64, f64)> = Vec::new();
    for p in v {
        if front.last().is_none_or(|l| p.2 > l.2 + FRONT_TIE_DB) {
            front.push(p);
        }
    }
    front
}

/// The method a user should take for rows summarised per method: the cheapest (one-thread
/// median) within `tolerance_db` of the best mean PSNR, and the best itself.
pub fn choice(per_method: &[(String, Summary)], tolerance_db: f64) -> Option<(String, String)> {
    let best = per_method
        .iter()
        .filter(|(_, s)| s.psnr.is_finite())
        .max_by(|a, b| a.1.psnr.total_cmp(&b.1.psnr))?;
    let cheap = per_method
        .iter()
        .filter(|(_, s)| s.psnr.is_finite() && s.psnr >= best.1.psnr - tolerance_db)
        .min_by(|a, b| a.1.p50_1t_ms.total_cmp(&b.1.p50_1t_ms))?;
    Some((best.0.clone(), cheap.0.clone()))
}

/// Rows grouped by `key`, then by method, in first-seen order of methods.
pub fn by(
    rows: &[Row],
    key: impl Fn(&Row) -> String,
) -> BTreeMap<String, Vec<(String, Vec<&Row>)>> {
    let mut out: BTreeMap<String, Vec<(String, Vec<&Row>)>> = BTreeMap::new();
    for r in rows {
        let methods = out.entry(key(r)).or_default();
        match methods.iter_mut().find(|(m, _)| *m == r.method) {
            Some((_, v)) => v.push(r),
            None => methods.push((r.method.clone(), vec![r])),
        }
    }
    out
}

/// `x` with `d` decimals, `-` when not finite.
pub fn fmt(x: f64, d: usize) -> String {
    if x.is_finite() {
        format!("{x:.d$}")
    } else {
        "-".to_string()
    }
}

/// Appends a markdown table of every method's summary.
pub fn method_table(md: &mut String, per_method: &[(String, Summary)]) {
    let _ = writeln!(
        md,
        "| method | PSNR dB | PSNR after gain | SSIM | 2D entropy | ms p50 / p99, 1 thread | ms p50, 2 threads | peak MiB | PSNR spread over textures dB |\n|---|---|---|---|---|---|---|---|---|"
    );
    for (m, s) in per_method {
        let _ = writeln!(
            md,
            "| {m}{} | {} | {} | {} | {} | {} / {} | {} | {} | {} |",
            if s.finite {
                ""
            } else {
                " (non-finite pixels!)"
            },
            fmt(s.psnr, 2),
            fmt(s.psnr_gain, 2),
            fmt(s.ssim, 3),
            fmt(s.entropy, 2),
            fmt(s.p50_1t_ms, 2),
            fmt(s.p99_1t_ms, 2),
            fmt(s.p50_2t_ms, 2),
            fmt(s.peak_mib, 1),
            fmt(s.spread_db, 2),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(method: &str, psnr: f64, cost: f64) -> Row {
        Row {
            set: "held-out".into(),
            class: "light1-speed0".into(),
            group: "bright static".into(),
            light: 1.0,
            speed_px_s: 0.0,
            texture: 0,
            label: "noise:1".into(),
            method: method.into(),
            frames: 4,
            exact: 0,
            finite: true,
            psnr,
            psnr_gain: psnr + 1.0,
            ssim: 0.5,
            entropy: f64::NAN,
            p50_1t_ms: cost,
            p99_1t_ms: cost * 2.0,
            p50_2t_ms: cost / 2.0,
            p99_2t_ms: f64::NAN,
            windows: 4,
            peak_mib: 1.5,
            rate: 0.25,
            event_rate: 0.001,
            change: 0.125,
            spread_decades: 0.5,
            edge: 0.0625,
        }
    }

    #[test]
    fn rows_round_trip_through_csv_and_bad_fields_are_named() {
        let r = row("tfp-33", 31.25, 0.125);
        // NaN fields (no entropy, no 2-thread p99) stay NaN: compare through the text.
        let back = Row::from_csv(&r.to_csv()).expect("parse");
        assert_eq!(back.to_csv(), r.to_csv());
        assert!(back.entropy.is_nan() && back.psnr == 31.25 && back.rate == 0.25);
        let bad = r.to_csv().replace(",31.2500,", ",x31,");
        let e = Row::from_csv(&bad).expect_err("bad psnr");
        assert!(e.contains("psnr") && e.contains("x31"), "{e}");
        assert!(
            Row::from_csv("a,b")
                .expect_err("short")
                .contains("2 fields")
        );
    }

    #[test]
    fn the_front_keeps_only_methods_nothing_beats_and_the_choice_is_the_cheapest_near_the_best() {
        let pts = vec![
            ("a".to_string(), 1.0, 20.0),
            ("b".to_string(), 2.0, 19.0), // beaten by a
            ("c".to_string(), 5.0, 30.0),
            ("d".to_string(), 50.0, 30.2),
            ("e".to_string(), 0.5, f64::NAN),
        ];
        let f: Vec<String> = pareto(&pts).into_iter().map(|p| p.0).collect();
        assert_eq!(f, ["a", "c", "d"]);
        // The same frames at a higher cost, their mean summed in another order: not on the front.
        let mut tied = pts.clone();
        tied.push(("c-again".to_string(), 6.0, 30.0 + 4.0 * f64::EPSILON * 30.0));
        let f: Vec<String> = pareto(&tied).into_iter().map(|p| p.0).collect();
        assert_eq!(f, ["a", "c", "d"]);
        let per: Vec<(String, Summary)> = pts
            .iter()
            .map(|(n, c, p)| (n.clone(), summarise(&[&row(n, *p, *c)])))
            .collect();
        assert_eq!(choice(&per, 0.5), Some(("d".into(), "c".into())));
        assert_eq!(choice(&per, 0.1), Some(("d".into(), "d".into())));
    }

    #[test]
    fn percentiles_and_means_have_defined_edges() {
        assert!(percentile(&[], 50.0).is_nan());
        assert_eq!(percentile(&[3.0, 1.0, 2.0], 50.0), 2.0);
        assert_eq!(percentile(&[3.0, 1.0, 2.0], 99.0), 3.0);
        assert_eq!(percentile(&[5.0], 0.0), 5.0);
        assert!(mean([f64::NAN, f64::INFINITY]).is_nan());
        assert_eq!(mean([1.0, f64::NAN, 3.0]), 2.0);
    }
}
