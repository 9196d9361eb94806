//! The policy of `--method auto`: which reconstruction method a window needs, chosen from cheap
//! statistics of the window ([`neuspike_representations::window_stats`]).
//!
//! A policy is a small table, fitted by `neuspike bench --fit-policy` from the bench's rows on
//! training textures only: one row per training recording (a scene class seen through one
//! texture), with the recording's mean window statistics, and the method chosen for its class:
//! the one that maximises `PSNR - db_per_ms * cost` (mean PSNR in dB over the class's textures,
//! median milliseconds of a frame on one thread), so that a method must buy `db_per_ms` decibels
//! with every millisecond it costs more. A window takes the method most of its `neighbours`
//! nearest rows name (the nearest row's on a tie), distance measured on the features
//!
//! | feature | from | edge |
//! |---|---|---|
//! | `log10(rate + 1e-4)` | spikes per pixel per plane | no spikes reads as `-4` |
//! | `log10((event_rate + 1e-6) / (edge + 0.01))` | motion: events per unit of texture | no events reads as `-6 - log10(edge + 0.01)` |
//! | `change` | change between the window's halves | in [0, 1] |
//! | `spread_decades` | dynamic range | `>= 0` |
//! | `log10(edge + 0.01)` | texture ([`WindowStats::edge`]) | a flat view reads as `-2` |
//!
//! (a moving scene's events grow with its speed and with how much texture it holds: the second
//! feature divides the texture out, so a flat scene moving fast is told from a busy one moving
//! slowly; the `0.01` floor keeps a flat view from reading as infinitely fast)
//! each divided by its `scale` (the file holds it; [`DEFAULT_SCALE`]: a factor of 2 in light,
//! in motion or in texture, or 0.3 decades of spread, is one unit; `change`, which Poisson noise dominates,
//! weighs little). Rows per recording rather than per class let the table cover how textures
//! move the statistics. The file is YAML with a format version and its provenance (command,
//! data, date); loading checks it whole, and that every method it chooses is installed.

use std::path::Path;

use neuspike_representations::WindowStats;
use serde::{Deserialize, Serialize};

/// The format version this module reads and writes.
pub const VERSION: u32 = 2;

/// Largest policy file read, bytes: a table of a few hundred rows is well under this.
pub const MAX_FILE_BYTES: u64 = 4 << 20;

/// The features' default scales (see the crate's documentation).
pub const DEFAULT_SCALE: [f64; FEATURES] = [0.3, 0.3, 1.0, 0.3, 0.3];

/// How many features a window has.
pub const FEATURES: usize = 5;

/// The default number of rows that vote.
pub const DEFAULT_NEIGHBOURS: usize = 3;

/// Why a policy cannot be used. Every message names the file and, where there is one, the field
/// and value.
#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    /// The file cannot be read.
    #[error("policy {path}: cannot read: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The file is not a policy.
    #[error("policy {path}: {what}")]
    Invalid {
        /// The file.
        path: String,
        /// What is wrong.
        what: String,
    },
}

/// Where a policy came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// The command that fitted it.
    pub command: String,
    /// The data it was fitted on (the bench CSV, its texture set and row count).
    pub data: String,
    /// When, UTC (RFC 3339).
    pub date: String,
}

/// One training recording: its class and its mean window statistics.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Row {
    /// The scene class it belongs to (one of the policy's `classes`).
    pub class: String,
    /// The recording's texture.
    pub texture: String,
    /// Mean spikes per pixel per plane.
    pub rate: f64,
    /// Mean events per pixel per plane.
    pub event_rate: f64,
    /// Mean change between the windows' halves.
    pub change: f64,
    /// Mean spread, decades.
    pub spread_decades: f64,
    /// Mean texture ([`WindowStats::edge`]).
    pub edge: f64,
}

/// A scene class of the training grid, and its method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Class {
    /// The class.
    pub class: String,
    /// The method for windows like these.
    pub method: String,
    /// Its mean PSNR on the class, dB.
    pub psnr_db: f64,
    /// The best method's mean PSNR on the class, dB.
    pub best_psnr_db: f64,
    /// Every method measured on the class, most accurate first: what a budget falls back on.
    pub ranked: Vec<Ranked>,
}

/// A method's figures on a class.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ranked {
    /// The method.
    pub method: String,
    /// Its mean PSNR, dB.
    pub psnr_db: f64,
    /// Its median cost of a frame on one thread where the policy was fitted, ms (a prior: a
    /// node measures its own).
    pub ms: f64,
    /// The same on two threads, where the bench measured it: the prior of a stage whose
    /// networks split a frame across two threads or more.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ms_2: Option<f64>,
}

impl Ranked {
    /// Its cost prior on `threads` threads: [`ms_2`](Self::ms_2) from two on where there is
    /// one, else [`ms`](Self::ms).
    pub fn ms_on(&self, threads: usize) -> f64 {
        match self.ms_2 {
            Some(ms) if threads >= 2 => ms,
            _ => self.ms,
        }
    }
}

/// The policy file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Policy {
    /// Format version ([`VERSION`]).
    pub version: u32,
    /// Where it came from.
    pub provenance: Provenance,
    /// The price of compute: decibels of PSNR a method must gain per extra millisecond of a
    /// frame (0: the most accurate method, whatever it costs).
    pub db_per_ms: f64,
    /// The features' scales: a difference of one scale counts as one unit of distance.
    pub scale: [f64; FEATURES],
    /// How many nearest rows vote.
    pub neighbours: usize,
    /// The classes and their methods.
    pub classes: Vec<Class>,
    /// The training recordings.
    pub rows: Vec<Row>,
}

/// The features of a window (or of a row's means), unscaled.
pub fn features(
    rate: f64,
    event_rate: f64,
    change: f64,
    spread_decades: f64,
    edge: f64,
) -> [f64; FEATURES] {
    // Negative or NaN inputs read as 0: log10 of the floor is the edge.
    let pos = |v: f64| if v.is_finite() && v > 0.0 { v } else { 0.0 };
    let texture = (pos(edge) + 0.01).log10();
    [
        (pos(rate) + 1e-4).log10(),
        (pos(event_rate) + 1e-6).log10() - texture,
        pos(change),
        pos(spread_decades),
        texture,
    ]
}

/// [`features`] of a window's statistics.
pub fn window_features(s: &WindowStats) -> [f64; FEATURES] {
    features(s.rate, s.event_rate, s.change, s.spread_decades, s.edge)
}

impl Row {
    fn features(&self) -> [f64; FEATURES] {
        features(
            self.rate,
            self.event_rate,
            self.change,
            self.spread_decades,
            self.edge,
        )
    }
}

impl Policy {
    /// A policy of `classes` (their methods chosen) and `rows`, with the default scales and vote.
    pub fn new(
        provenance: Provenance,
        db_per_ms: f64,
        classes: Vec<Class>,
        rows: Vec<Row>,
    ) -> Policy {
        Policy {
            version: VERSION,
            provenance,
            db_per_ms,
            scale: DEFAULT_SCALE,
            neighbours: DEFAULT_NEIGHBOURS,
            classes,
            rows,
        }
    }

    /// The class `name`.
    pub fn class(&self, name: &str) -> Option<&Class> {
        self.classes.iter().find(|c| c.class == name)
    }

    /// Reads and checks a policy file: size, format, version, finite values, at least one row,
    /// and that every row's method is among `installed` (a ranked fallback that is not installed
    /// is allowed: a user of the policy skips it).
    ///
    /// # Errors
    /// [`PolicyError`] naming the file, and the field and value at fault.
    pub fn load(path: &Path, installed: &[&str]) -> Result<Policy, PolicyError> {
        let p = Policy::read(path)?;
        p.check(Some(installed))
            .map_err(|what| PolicyError::Invalid {
                path: path.display().to_string(),
                what,
            })?;
        Ok(p)
    }

    /// Reads a policy file and checks everything but the installation: size, format, version,
    /// finite values, at least one row.
    ///
    /// # Errors
    /// [`PolicyError`] naming the file, and the field and value at fault.
    pub fn read(path: &Path) -> Result<Policy, PolicyError> {
        let name = path.display().to_string();
        let read = |source| PolicyError::Read {
            path: name.clone(),
            source,
        };
        let len = std::fs::metadata(path).map_err(read)?.len();
        let invalid = |what: String| PolicyError::Invalid {
            path: name.clone(),
            what,
        };
        if len > MAX_FILE_BYTES {
            return Err(invalid(format!(
                "{len} bytes; a policy is at most {MAX_FILE_BYTES}"
            )));
        }
        let text = std::fs::read_to_string(path).map_err(read)?;
        Policy::from_yaml(&text, &name)
    }

    /// A policy from the text of a file (`name` is what errors call it), checked as
    /// [`Self::read`] checks it: format, version, finite values, at least one row, every row's
    /// class among the classes.
    ///
    /// # Errors
    /// [`PolicyError::Invalid`] naming `name`, and the field and value at fault.
    pub fn from_yaml(text: &str, name: &str) -> Result<Policy, PolicyError> {
        let invalid = |what: String| PolicyError::Invalid {
            path: name.to_string(),
            what,
        };
        let p: Policy = serde_yaml::from_str(text).map_err(|e| invalid(e.to_string()))?;
        p.check(None).map_err(invalid)?;
        Ok(p)
    }

    /// Every method the file names, chosen or ranked, sorted.
    pub fn all_methods(&self) -> Vec<&str> {
        let mut v: Vec<&str> = self
            .classes
            .iter()
            .flat_map(|r| {
                std::iter::once(r.method.as_str()).chain(r.ranked.iter().map(|k| k.method.as_str()))
            })
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// Checks the table, and with `installed` that every row's method is among them; the error
    /// names the field and value.
    pub fn check(&self, installed: Option<&[&str]>) -> Result<(), String> {
        if self.version != VERSION {
            return Err(format!(
                "version {} (this neuspike reads version {VERSION}: fit the policy again)",
                self.version
            ));
        }
        if self.rows.is_empty() {
            return Err("rows: empty (a policy needs at least one row)".into());
        }
        if self.neighbours == 0 {
            return Err("neighbours = 0: at least one row must vote".into());
        }
        for (k, s) in self.scale.iter().enumerate() {
            if !(s.is_finite() && *s > 0.0) {
                return Err(format!("scale[{k}] = {s}: must be finite and > 0"));
            }
        }
        if !(self.db_per_ms.is_finite() && self.db_per_ms >= 0.0) {
            return Err(format!(
                "db_per_ms = {}: must be finite and >= 0",
                self.db_per_ms
            ));
        }
        for (i, r) in self.rows.iter().enumerate() {
            for (field, v) in [
                ("rate", r.rate),
                ("event_rate", r.event_rate),
                ("change", r.change),
                ("spread_decades", r.spread_decades),
                ("edge", r.edge),
            ] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(format!(
                        "rows[{i}] ({}): {field} = {v}: must be finite and >= 0",
                        r.class
                    ));
                }
            }
            if self.class(&r.class).is_none() {
                return Err(format!(
                    "rows[{i}]: class {:?} is not among the classes",
                    r.class
                ));
            }
        }
        for (i, c) in self.classes.iter().enumerate() {
            for (j, k) in c.ranked.iter().enumerate() {
                if !(k.ms.is_finite() && k.ms >= 0.0) {
                    return Err(format!(
                        "classes[{i}] ({}): ranked[{j}].ms = {}: must be finite and >= 0",
                        c.class, k.ms
                    ));
                }
            }
            if let Some(installed) = installed
                && !installed.contains(&c.method.as_str())
            {
                return Err(format!(
                    "classes[{i}] ({}): method {:?} is not installed (installed: {})",
                    c.class,
                    c.method,
                    installed.join(", ")
                ));
            }
        }
        Ok(())
    }

    /// The policy for a node that can run only the methods `runnable` accepts (a recording
    /// without events: no event filter, fusion or network that reads events; windows too short
    /// for TFP over many planes). Each class keeps the ranked methods that can run and chooses
    /// among them as the fit chose ([`best_value`] at the same `db_per_ms`). With `no_events`
    /// every row's event rate reads as 0, as every window's will, so the event rate no longer
    /// separates rows.
    ///
    /// # Errors
    /// A class has no method that can run; the message names it and what it ranks.
    pub fn restricted(
        &self,
        runnable: impl Fn(&str) -> bool,
        no_events: bool,
    ) -> Result<Policy, String> {
        let mut p = self.clone();
        for c in &mut p.classes {
            let all: Vec<String> = c.ranked.iter().map(|k| k.method.clone()).collect();
            c.ranked.retain(|k| runnable(&k.method));
            let candidates: Vec<(String, f64, f64)> = c
                .ranked
                .iter()
                .map(|k| (k.method.clone(), k.psnr_db, k.ms))
                .collect();
            let Some((method, psnr, _)) = best_value(&candidates, self.db_per_ms).cloned() else {
                return Err(format!(
                    "class {:?}: none of its methods ({}) can run here",
                    c.class,
                    all.join(", ")
                ));
            };
            c.method = method;
            c.psnr_db = psnr;
        }
        if no_events {
            for r in &mut p.rows {
                r.event_rate = 0.0;
            }
        }
        Ok(p)
    }

    /// The policy as the text of its file: YAML, after a comment saying what it is (the caller
    /// writes it whole, e.g. through `neuspike_formats::atomic`).
    pub fn to_yaml(&self) -> String {
        // A policy is plain data (strings, finite numbers, lists): it always serialises.
        let yaml = serde_yaml::to_string(self).unwrap_or_default();
        format!(
            "# neuspike --method auto: each window takes the method most of its nearest rows \
             choose, on the scaled features of its statistics (see neuspike_reconstruction::policy).\n{yaml}"
        )
    }

    /// The rows nearest to a window's statistics, nearest first (at most `neighbours`).
    fn nearest_rows(&self, s: &WindowStats) -> Vec<(f64, &Row)> {
        let f = window_features(s);
        let mut d: Vec<(f64, &Row)> = self
            .rows
            .iter()
            .map(|r| {
                let x: f64 = r
                    .features()
                    .iter()
                    .zip(&f)
                    .zip(&self.scale)
                    .map(|((a, b), sc)| ((a - b) / sc).powi(2))
                    .sum();
                (x, r)
            })
            .collect();
        // Stable: equal distances keep the table's order.
        d.sort_by(|a, b| a.0.total_cmp(&b.0));
        d.truncate(self.neighbours.max(1));
        d
    }

    /// The class a window belongs to: the one most of its nearest rows belong to, the nearest
    /// row's on a tie. Its method is the window's; its ranked methods are what a budget falls
    /// back on.
    pub fn nearest_class(&self, s: &WindowStats) -> &Class {
        let near = self.nearest_rows(s);
        let mut best: Option<(&str, usize)> = None;
        for (_, r) in &near {
            let votes = near.iter().filter(|(_, o)| o.class == r.class).count();
            if best.is_none_or(|(_, v)| votes > v) {
                best = Some((&r.class, votes));
            }
        }
        best.and_then(|(c, _)| self.class(c))
            .unwrap_or(&self.classes[0])
    }

    /// The class of a window whose features cannot tell its scene's classes apart (without
    /// events, the speed: spikes alone barely show motion): the `k` nearest rows pooled, each
    /// method ranked by its mean PSNR over their classes (with its mean cost), and the method of
    /// best mean value ([`best_value`]) chosen: the best choice on average over what the window
    /// may be. Methods not ranked in every pooled class are left out; with none left, the
    /// nearest class.
    pub fn pooled_class(&self, s: &WindowStats, k: usize) -> Class {
        let mut pooled = self.clone();
        pooled.neighbours = k.max(1);
        let near = pooled.nearest_rows(s);
        let classes: Vec<&Class> = near
            .iter()
            .filter_map(|(_, r)| self.class(&r.class))
            .collect();
        let Some(first) = classes.first() else {
            return self.nearest_class(s).clone();
        };
        let mut ranked: Vec<Ranked> = first
            .ranked
            .iter()
            .filter_map(|m| {
                let figures: Vec<&Ranked> = classes
                    .iter()
                    .filter_map(|c| c.ranked.iter().find(|k| k.method == m.method))
                    .collect();
                (figures.len() == classes.len()).then(|| {
                    let n = figures.len() as f64;
                    Ranked {
                        method: m.method.clone(),
                        psnr_db: figures.iter().map(|k| k.psnr_db).sum::<f64>() / n,
                        ms: figures.iter().map(|k| k.ms).sum::<f64>() / n,
                        ms_2: figures
                            .iter()
                            .map(|k| k.ms_2)
                            .sum::<Option<f64>>()
                            .map(|t| t / n),
                    }
                })
            })
            .collect();
        ranked.sort_by(|a, b| b.psnr_db.total_cmp(&a.psnr_db));
        let candidates: Vec<(String, f64, f64)> = ranked
            .iter()
            .map(|k| (k.method.clone(), k.psnr_db, k.ms))
            .collect();
        let Some((method, psnr_db, _)) = best_value(&candidates, self.db_per_ms).cloned() else {
            return self.nearest_class(s).clone();
        };
        Class {
            class: format!("{} rows near {}", classes.len(), first.class),
            method,
            psnr_db,
            best_psnr_db: ranked.first().map_or(psnr_db, |k| k.psnr_db),
            ranked,
        }
    }

    /// The method for a window: its class's ([`Self::nearest_class`]).
    pub fn choose(&self, s: &WindowStats) -> &str {
        &self.nearest_class(s).method
    }

    /// Every method the table chooses, in first-seen order.
    pub fn methods(&self) -> Vec<&str> {
        let mut out: Vec<&str> = Vec::new();
        for c in &self.classes {
            if !out.contains(&c.method.as_str()) {
                out.push(&c.method);
            }
        }
        out
    }
}

/// A method as the bench and the policy name it: `tfp-<planes>`, `tfi`, `tfstp`, `hf`, `cf`,
/// `fusion`, `fusion-tfp`, or a network by its ONNX file's stem (`neuspike-fused-8`, any other name).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MethodName {
    /// TFP over this many planes (at least 1).
    Tfp(u32),
    /// TFI.
    Tfi,
    /// TFSTP.
    Tfstp,
    /// The high-pass filter (events).
    Hf,
    /// The complementary filter.
    Cf,
    /// The physics fusion on ISIs (Eq. 5-7).
    Fusion,
    /// The physics fusion on TFP rates (`fusion-tfp`).
    FusionTfp,
    /// A network: `<models>/<name>.onnx`.
    Network(String),
}

impl MethodName {
    /// Parses a name; `tfp-` must be followed by a plane count in `1..=100_000`.
    pub fn parse(s: &str) -> Result<MethodName, String> {
        Ok(match s {
            "tfi" => MethodName::Tfi,
            "tfstp" => MethodName::Tfstp,
            "hf" => MethodName::Hf,
            "cf" => MethodName::Cf,
            "fusion" => MethodName::Fusion,
            "fusion-tfp" => MethodName::FusionTfp,
            _ => match s.strip_prefix("tfp-") {
                Some(n) => match n.parse::<u32>() {
                    Ok(n @ 1..=100_000) => MethodName::Tfp(n),
                    _ => return Err(format!("method {s:?}: TFP's planes must be in 1..=100000")),
                },
                None if !s.is_empty()
                    && !s.starts_with('.')
                    && s.chars()
                        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.')) =>
                {
                    MethodName::Network(s.to_string())
                }
                None => return Err(format!("method {s:?}: not a method name")),
            },
        })
    }
}

impl std::fmt::Display for MethodName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MethodName::Tfp(n) => write!(f, "tfp-{n}"),
            MethodName::Tfi => f.write_str("tfi"),
            MethodName::Tfstp => f.write_str("tfstp"),
            MethodName::Hf => f.write_str("hf"),
            MethodName::Cf => f.write_str("cf"),
            MethodName::Fusion => f.write_str("fusion"),
            MethodName::FusionTfp => f.write_str("fusion-tfp"),
            MethodName::Network(n) => f.write_str(n),
        }
    }
}

/// The method to choose among `(name, mean PSNR dB, cost ms)` candidates: the one that
/// maximises `PSNR - db_per_ms * cost` (the first of equals); `None` when no candidate has a
/// finite PSNR and cost.
pub fn best_value(
    candidates: &[(String, f64, f64)],
    db_per_ms: f64,
) -> Option<&(String, f64, f64)> {
    let value = |c: &(String, f64, f64)| c.1 - db_per_ms * c.2;
    candidates
        .iter()
        .filter(|c| c.1.is_finite() && c.2.is_finite())
        .fold(None, |best: Option<&(String, f64, f64)>, c| match best {
            Some(b) if value(b) >= value(c) => Some(b),
            _ => Some(c),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(class: &str, rate: f64, event_rate: f64) -> Row {
        Row {
            class: class.into(),
            texture: "noise:1".into(),
            rate,
            event_rate,
            change: 0.1,
            spread_decades: 0.2,
            edge: 0.05,
        }
    }

    fn class(class: &str, method: &str) -> Class {
        Class {
            class: class.into(),
            method: method.into(),
            psnr_db: 30.0,
            best_psnr_db: 31.0,
            ranked: vec![Ranked {
                method: method.into(),
                psnr_db: 30.0,
                ms: 0.5,
                ms_2: None,
            }],
        }
    }

    fn policy() -> Policy {
        Policy::new(
            Provenance {
                command: "neuspike bench --set train --fit-policy p.yml".into(),
                data: "bench.csv (train, 100 rows)".into(),
                date: "2026-11-26T03:00:00Z".into(),
            },
            0.04,
            vec![
                class("bright static", "tfp-256"),
                class("dark fast", "neuspike-fused-8"),
            ],
            vec![
                row("bright static", 0.5, 0.0),
                row("dark fast", 0.02, 0.01),
                row("dark fast", 0.03, 0.02),
            ],
        )
    }

    #[test]
    fn a_restricted_policy_chooses_among_what_can_run_and_ignores_the_event_rate() {
        let mut p = policy();
        p.classes[1].ranked = vec![
            Ranked {
                method: "neuspike-fused-8".into(),
                psnr_db: 30.0,
                ms: 40.0,
                ms_2: None,
            },
            Ranked {
                method: "neuspike-spike-8".into(),
                psnr_db: 26.0,
                ms: 20.0,
                ms_2: None,
            },
            Ranked {
                method: "tfstp".into(),
                psnr_db: 25.5,
                ms: 2.0,
                ms_2: None,
            },
        ];
        let spikes_only = |m: &str| !m.contains("fused");
        let r = p.restricted(spikes_only, true).expect("restricted");
        // 26 - 0.04 * 20 = 25.2 < 25.5 - 0.04 * 2 = 25.42: TFSTP is the better value.
        assert_eq!(r.classes[1].method, "tfstp");
        assert_eq!(r.classes[1].psnr_db, 25.5);
        assert_eq!(r.classes[1].ranked.len(), 2);
        assert_eq!(r.classes[0].method, "tfp-256");
        assert!(r.rows.iter().all(|row| row.event_rate == 0.0));
        // With events the rows keep their rates.
        let kept = p.restricted(spikes_only, false).expect("restricted");
        assert_eq!(kept.rows[1].event_rate, 0.01);
        // A class left with nothing names itself and what it ranked.
        let err = p
            .restricted(|m| m == "tfstp", true)
            .expect_err("nothing runs");
        assert!(
            err.contains("\"bright static\"") && err.contains("tfp-256"),
            "{err}"
        );
    }

    #[test]
    fn a_pooled_class_takes_the_best_value_on_average_over_its_rows() {
        let ranked = |a: f64, b: f64| {
            vec![
                Ranked {
                    method: "tfstp".into(),
                    psnr_db: a,
                    ms: 1.0,
                    ms_2: None,
                },
                Ranked {
                    method: "neuspike-spike-8".into(),
                    psnr_db: b,
                    ms: 10.0,
                    ms_2: None,
                },
            ]
        };
        let mut p = policy();
        // Two classes the features cannot tell apart: TFSTP wins one by far, the network the
        // other by a little; on average TFSTP is the better choice.
        p.classes = vec![
            Class {
                ranked: ranked(33.0, 23.0),
                ..class("dark still", "tfstp")
            },
            Class {
                ranked: ranked(17.0, 22.0),
                ..class("dark fast", "neuspike-spike-8")
            },
        ];
        p.rows = vec![row("dark still", 0.03, 0.0), row("dark fast", 0.03, 0.0)];
        let s = WindowStats {
            rate: 0.03,
            ..WindowStats::default()
        };
        let c = p.pooled_class(&s, 2);
        assert_eq!(c.method, "tfstp");
        assert_eq!(c.psnr_db, 25.0);
        assert_eq!(c.ranked[1].method, "neuspike-spike-8");
        assert_eq!(c.ranked[1].psnr_db, 22.5);
        // Pooling one row is the nearest class.
        assert_eq!(p.pooled_class(&s, 1).method, "tfstp");
        p.classes[0].ranked = ranked(23.0, 33.0);
        assert_eq!(p.pooled_class(&s, 2).method, "neuspike-spike-8");
    }

    #[test]
    fn a_policy_round_trips_and_its_nearest_rows_vote() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("policy.yml");
        let mut p = policy();
        p.neighbours = 1;
        // A two-thread cost where the bench measured one: written, read back, and the prior
        // from two threads on; without one, the one-thread cost everywhere.
        p.classes[1].ranked[0].ms_2 = Some(0.3);
        std::fs::write(&path, p.to_yaml()).expect("save");
        let installed = ["tfp-256", "neuspike-fused-8", "tfi"];
        let q = Policy::load(&path, &installed).expect("load");
        assert_eq!(p, q);
        let (two, one) = (&q.classes[1].ranked[0], &q.classes[0].ranked[0]);
        assert_eq!([two.ms_on(1), two.ms_on(2), two.ms_on(4)], [0.5, 0.3, 0.3]);
        assert_eq!([one.ms_on(1), one.ms_on(2)], [0.5, 0.5]);
        let bright = WindowStats {
            rate: 0.45,
            ..WindowStats::default()
        };
        assert_eq!(q.choose(&bright), "tfp-256");
        let dark = WindowStats {
            rate: 0.03,
            event_rate: 0.008,
            events: true,
            ..WindowStats::default()
        };
        assert_eq!(q.choose(&dark), "neuspike-fused-8");
        assert_eq!(q.methods(), ["tfp-256", "neuspike-fused-8"]);
        assert_eq!(q.nearest_class(&bright).class, "bright static");
        // With one row voting, the nearest decides; with all three, the majority does.
        let mut one = q.clone();
        one.neighbours = 1;
        assert_eq!(one.choose(&bright), "tfp-256");
        let mut all = q.clone();
        all.neighbours = 3;
        assert_eq!(all.choose(&bright), "neuspike-fused-8");
    }

    #[test]
    fn a_policy_that_does_not_fit_the_installation_or_the_format_is_refused_by_name() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("policy.yml");
        std::fs::write(&path, policy().to_yaml()).expect("save");
        let e = Policy::load(&path, &["tfp-256"])
            .expect_err("missing method")
            .to_string();
        assert!(
            e.contains("policy.yml") && e.contains("classes[1]") && e.contains("neuspike-fused-8"),
            "{e}"
        );
        let text = std::fs::read_to_string(&path).expect("read");
        for (bad, want) in [
            (text.replace("version: 2", "version: 9"), "version 9"),
            // A policy of the earlier format (four features): fit again.
            (
                text.replace("version: 2", "version: 1"),
                "fit the policy again",
            ),
            (text.replace("edge: 0.05", "edge: -1.0"), "edge = -1"),
            (
                text.replace("db_per_ms: 0.04", "db_per_ms: -1.0"),
                "db_per_ms = -1",
            ),
            (text.replace("rate: 0.5", "rate: .nan"), "rate = NaN"),
            (text.replace("db_per_ms", "tolerance"), "unknown field"),
            ("not: [a, policy".to_string(), "policy.yml"),
        ] {
            std::fs::write(&path, bad).expect("write");
            let e = Policy::load(&path, &["tfp-256", "neuspike-fused-8"])
                .expect_err(want)
                .to_string();
            assert!(e.contains(want) && e.contains("policy.yml"), "{want}: {e}");
        }
        let e = Policy::load(&dir.path().join("absent.yml"), &[]).expect_err("absent");
        assert!(e.to_string().contains("absent.yml"), "{e}");
    }

    #[test]
    fn method_names_parse_and_print_back() {
        for s in [
            "tfp-8",
            "tfp-256",
            "tfi",
            "tfstp",
            "hf",
            "cf",
            "fusion",
            "neuspike-fused-8",
        ] {
            assert_eq!(MethodName::parse(s).expect(s).to_string(), s);
        }
        assert_eq!(MethodName::parse("tfp-33"), Ok(MethodName::Tfp(33)));
        for bad in ["tfp-0", "tfp-x", "", "a b", "../x", ".."] {
            assert!(MethodName::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_best_value_is_chosen_and_features_have_defined_edges() {
        let c = vec![
            ("a".to_string(), 30.0, 100.0),
            ("b".to_string(), 29.6, 10.0),
            ("c".to_string(), 25.0, 1.0),
            ("d".to_string(), f64::NAN, 0.1),
        ];
        // 0.04 dB/ms: b (29.6 - 0.4) beats a (30 - 4) and c (25 - 0.04).
        assert_eq!(best_value(&c, 0.04).map(|x| x.0.as_str()), Some("b"));
        assert_eq!(best_value(&c, 0.0).map(|x| x.0.as_str()), Some("a"));
        assert_eq!(best_value(&c, 10.0).map(|x| x.0.as_str()), Some("c"));
        assert_eq!(best_value(&c[3..], 0.5), None);
        // No spikes, no events, no texture: each feature at its floor.
        let f = features(0.0, f64::NAN, -1.0, f64::INFINITY, f64::NAN);
        assert_eq!(f, [-4.0, -4.0, 0.0, 0.0, -2.0]);
    }

    #[test]
    fn motion_divides_the_texture_out() {
        // A flat scene moving fast and a busy one moving slowly fire the same events; the
        // motion feature tells them apart, and a busy scene with as many events per unit of
        // texture (the edge plus its floor: 0.21 against 0.03) reads as moving at the same speed.
        let flat_fast = features(0.2, 0.01, 0.03, 0.1, 0.02);
        let busy_slow = features(0.2, 0.01, 0.03, 0.1, 0.2);
        assert!(
            flat_fast[1] - busy_slow[1] > 0.8,
            "{flat_fast:?} {busy_slow:?}"
        );
        let busy_fast = features(0.2, 0.07, 0.03, 0.1, 0.2);
        assert!((busy_fast[1] - flat_fast[1]).abs() < 0.01, "{busy_fast:?}");
        // The nearest row follows the motion, not the raw event rate.
        let mut p = policy();
        p.neighbours = 1;
        p.rows = vec![
            Row {
                edge: 0.02,
                ..row("bright static", 0.2, 0.0005)
            },
            Row {
                edge: 0.02,
                ..row("dark fast", 0.2, 0.01)
            },
        ];
        let busy = WindowStats {
            rate: 0.2,
            event_rate: 0.01,
            change: 0.1,
            spread_decades: 0.2,
            events: true,
            edge: 0.4,
        };
        assert_eq!(p.nearest_class(&busy).class, "bright static");
    }
}
