//! `--method auto`: per window, the method the scene needs, from a policy fitted by
//! `neuspike bench` (`crate::policy`). The stage reads align's windows itself and computes only
//! what the chosen method reads: a window that needs TFP never pays for a network's inputs.
//!
//! Per window: the statistics of its 33 central planes, the event rate also over the longest
//! method's planes ([`neuspike_representations::choice_stats`], read where they lie, the events
//! counted, not copied), the policy's nearest rows, and their method; the method reads a crop of the window,
//! with the events copied only for a network that reads them. Candidates are TFP over any
//! window, TFI, TFSTP and the networks in `--models`; TFSTP's synapses are fed every window
//! whether chosen or not, so that it is current when chosen (its cost counts on every window).
//!
//! **Budget mode** (`--budget-ms X`): the method is instead the most accurate of the class's
//! ranked methods whose expected cost fits in [`PLAN_SHARE`] of the deadline after the
//! statistics, else the cheapest candidate; TFSTP's upkeep runs beside it where it fits too
//! (else TFSTP misses those planes: its `gaps`), so this frame's accuracy comes before keeping
//! TFSTP current for later ones. Expected costs start from
//! the policy's figures (measured where it was fitted) and follow this machine: each run updates
//! its method's estimate (an exponentially weighted mean of the last runs, weight
//! [`COST_WEIGHT`], taking a slower run at once; a frame that does not run a method moves an
//! estimate above the policy's figure back towards it by the same weight, so that one slow run
//! does not rule a method out for good), so load makes the stage fall back to cheaper methods
//! instead of behind the camera. A frame whose whole cost exceeds the budget is late,
//! and counted.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::policy::{MethodName, Policy};
use ndarray::{Array2, Axis};
use neuspike_representations::{RepresentConfig, Representer, choice_stats, window_stats};
use neuspike_schemas::{AlignedWindow, RepresentationKind};

use crate::learned::{ConvPath, LearnedModel, LearnedOutput};
use crate::{InferError, luminance_from_isi_into, luminance_from_rate_into};

/// The planes the statistics and the 33-plane methods (TFI, TFSTP, the networks) read.
pub const STATS_PLANES: usize = 33;

/// The planes of the longest window any method of `policy` reads: TFP over its planes,
/// [`STATS_PLANES`] for the others (and at least that). Align's windows for `auto` must be this
/// long for every method to be at hand.
pub fn longest_window(policy: &Policy) -> u32 {
    let stats = STATS_PLANES as u32;
    policy
        .all_methods()
        .into_iter()
        .map(|m| match MethodName::parse(m) {
            Ok(MethodName::Tfp(n)) => n,
            _ => stats,
        })
        .max()
        .unwrap_or(stats)
        .max(stats)
}

/// Weight of the newest run in a method's cost estimate.
pub const COST_WEIGHT: f64 = 0.1;

/// Rows pooled for a window without events ([`Policy::pooled_class`]): without events the
/// statistics barely tell a scene's speeds apart, so a window takes the method best on average
/// over the policy's five speeds at the three nearest light levels and textures.
pub const NO_EVENT_ROWS: usize = 15;

/// Under a budget, the share of it a frame is planned to take.
pub const PLAN_SHARE: f64 = 0.7;

enum Engine {
    Tfp,
    Tfi,
    Tfstp,
    Net(Box<LearnedModel>),
}

struct Candidate {
    name: String,
    engine: Engine,
    /// Planes of its window.
    planes: usize,
    represent: Representer,
    /// Expected milliseconds of a frame.
    cost_ms: f64,
    /// The policy's figure, where [`Self::cost_ms`] starts.
    prior_ms: f64,
}

/// Counts of a run, per method.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AutoStats {
    /// Frames per method.
    pub frames: BTreeMap<String, u64>,
    /// Nanoseconds spent per method (its frames, the statistics included).
    pub compute_ns: BTreeMap<String, u64>,
    /// Frames over the budget.
    pub late: u64,
    /// Per-region choice: tiles per method ([`REUSED`] for the reused ones).
    pub tiles: BTreeMap<String, u64>,
}

/// One window's frame and how it was made.
#[derive(Clone, Debug)]
pub struct AutoFrame {
    /// Luminance in [0, 1].
    pub data: Array2<f32>,
    /// The method that made it.
    pub method: String,
    /// Its whole cost: statistics, upkeep, representation and reconstruction.
    pub compute_ns: i64,
    /// Whether it took longer than the budget.
    pub late: bool,
    /// Per-region choice: the tiles each method made, most first (empty when one method made
    /// the whole frame).
    pub regions: Vec<(String, usize)>,
}

impl Candidate {
    /// A run's milliseconds into the estimate: taken at once when slower (load arrives
    /// suddenly), averaged in with [`COST_WEIGHT`] when faster.
    fn update_cost(&mut self, ms: f64) {
        self.cost_ms = if ms > self.cost_ms {
            ms
        } else {
            (1.0 - COST_WEIGHT) * self.cost_ms + COST_WEIGHT * ms
        };
    }

    /// A frame that did not run it: an estimate above the policy's figure moves back towards
    /// it by [`COST_WEIGHT`], so that one slow run (a burst of load, a cold cache) does not rule
    /// a method out for good; if it is still slow when tried again, its next run says so.
    fn forget(&mut self) {
        if self.cost_ms > self.prior_ms {
            self.cost_ms = (1.0 - COST_WEIGHT) * self.cost_ms + COST_WEIGHT * self.prior_ms;
        }
    }
}

/// The auto stage.
pub struct Auto {
    policy: Policy,
    candidates: Vec<Candidate>,
    budget_ms: Option<f64>,
    lum_per_rate: Option<f64>,
    /// The stream has no events ([`Auto::restrict`]): windows read as eventless to the policy.
    no_events: bool,
    /// Per-region choice: the tiles' width and height ([`Auto::with_regions`]).
    tiles: Option<(usize, usize)>,
    /// Per-region choice: the last frame, whose still tiles the next one reuses, and the
    /// candidate that made each of its tiles.
    previous: Option<(Array2<f32>, Vec<usize>)>,
    stats: AutoStats,
}

/// The name a reused tile goes by in a frame's mix.
pub const REUSED: &str = "reused";

/// A rectangle of the spike grid: `(x0, y0, width, height)`.
pub type Rect = (usize, usize, usize, usize);

/// Pixels of context a network reads around the tiles it reconstructs (beyond them its output
/// is cut away): its receptive field's reach, so that the tiles' pixels are those of the
/// network run on the whole frame, up to the last few (see the test).
pub const NET_MARGIN: usize = 16;

/// The file of network method `name` (`<models>/<name>.onnx`, or the stem's for an 8-bit
/// variant: [`crate::learned::network_variant`]).
fn model_file(models: &Path, name: &str) -> PathBuf {
    let (stem, _) = crate::learned::network_variant(name);
    models.join(format!("{stem}.onnx"))
}

impl Auto {
    /// Loads the policy and every method it names; the networks from `models`. Each method's
    /// cost prior is the policy's figure for the threads the networks run on when it is made
    /// (`learned::set_threads`: its two-thread figure from two threads on, where it has one).
    ///
    /// # Errors
    /// The policy does not load or names a method auto cannot run (the event filters and the
    /// fusion), a network is missing or broken, or the budget is not finite and `> 0`.
    pub fn new(
        policy: &Path,
        models: &Path,
        budget_ms: Option<f64>,
        lum_per_rate: Option<f64>,
        conv: ConvPath,
    ) -> Result<Auto, InferError> {
        if let Some(b) = budget_ms
            && !(b.is_finite() && b > 0.0)
        {
            return Err(InferError::Param {
                name: "budget-ms",
                value: b,
                reason: "must be finite and > 0",
            });
        }
        let wiring = |what: String| InferError::Wiring(format!("auto: {what}"));
        let read = Policy::read(policy).map_err(|e| wiring(e.to_string()))?;
        // What auto can run of what the file names: TFP, TFI, TFSTP and the networks found in
        // `models`. Every row's choice must be among them (the check names the one that is
        // not); ranked fallbacks it cannot run (the event filters, the fusion) are skipped.
        let installed: Vec<String> = read
            .all_methods()
            .into_iter()
            .filter(|n| match MethodName::parse(n) {
                Ok(MethodName::Tfp(_) | MethodName::Tfi | MethodName::Tfstp) => true,
                Ok(MethodName::Network(m)) => model_file(models, &m).is_file(),
                _ => false,
            })
            .map(str::to_string)
            .collect();
        let refs: Vec<&str> = installed.iter().map(String::as_str).collect();
        let policy = Policy::load(policy, &refs).map_err(|e| {
            wiring(format!(
                "{e} (auto runs tfp-N, tfi, tfstp and the networks in {})",
                models.display()
            ))
        })?;
        let mut candidates = Vec::new();
        // Cost priors for the threads the networks run on now (`learned::set_threads`).
        let threads = crate::learned::threads();
        for name in &installed {
            // Cost prior: the median of the figures the policy holds for it.
            let mut prior: Vec<f64> = policy
                .classes
                .iter()
                .flat_map(|r| r.ranked.iter())
                .filter(|k| k.method == *name)
                .map(|k| k.ms_on(threads))
                .collect();
            prior.sort_by(f64::total_cmp);
            let cost_ms = prior.get(prior.len() / 2).copied().unwrap_or(0.0);
            let mut cfg = RepresentConfig::default();
            let (engine, planes) = match MethodName::parse(name) {
                Ok(MethodName::Tfp(n)) => (Engine::Tfp, n as usize),
                Ok(MethodName::Tfi) => (Engine::Tfi, STATS_PLANES),
                Ok(MethodName::Tfstp) => (Engine::Tfstp, STATS_PLANES),
                Ok(MethodName::Network(m)) => {
                    let mut net = LearnedModel::load(&model_file(models, &m))?;
                    net.set_conv_path(conv);
                    // Plain loops in a reduced precision run `f32` (slower otherwise).
                    let asked = crate::learned::network_variant(&m).1;
                    let precision = crate::learned::effective_precision(asked);
                    if precision != asked {
                        tracing::warn!(
                            method = %m,
                            "auto: {asked} has no vector path on this CPU (8 bits: AVX-512 \
                             VNNI or AMX; bf16: AVX-512 BF16): running it in f32"
                        );
                    }
                    net.set_precision(precision);
                    cfg = net.represent_config();
                    (Engine::Net(Box::new(net)), STATS_PLANES)
                }
                _ => continue,
            };
            candidates.push(Candidate {
                name: name.clone(),
                engine,
                planes,
                represent: Representer::new(cfg).map_err(|e| wiring(e.to_string()))?,
                cost_ms,
                prior_ms: cost_ms,
            });
        }
        Ok(Auto {
            policy,
            candidates,
            budget_ms,
            lum_per_rate,
            no_events: false,
            tiles: None,
            previous: None,
            stats: AutoStats::default(),
        })
    }

    /// Chooses per region: the grid is cut into tiles of `width` x `height` pixels (the last
    /// row and column take what is left), each tile takes the method its own statistics choose,
    /// and each chosen method runs once, over the smallest rectangle that holds its tiles (a
    /// network with [`NET_MARGIN`] pixels of context around it; TFSTP, whose synapses cover
    /// the grid, over the whole grid). A tile without a single event over the longest method's
    /// planes reuses the previous frame's pixels ([`REUSED`]) when they were made by the method
    /// its statistics choose now, unless that is TFSTP (whose estimate keeps improving as its
    /// synapses settle): an event camera fires wherever the log intensity changes, so where it
    /// is silent nothing moved and the light did not change, and the same method on the same
    /// still scene makes the same pixels. A stream without events (`restrict`'s
    /// `spikes_only`) reuses nothing. A window
    /// whose tiles all agree costs what the whole-frame choice costs, plus the tiles'
    /// statistics.
    ///
    /// # Errors
    /// A tile side of 0, or a budget (which plans one method a frame).
    pub fn with_regions(mut self, width: usize, height: usize) -> Result<Auto, InferError> {
        if width == 0 || height == 0 {
            return Err(InferError::Wiring(format!(
                "auto: regions {width}x{height}: a tile needs at least one pixel a side"
            )));
        }
        if self.budget_ms.is_some() {
            return Err(InferError::Wiring(
                "auto: --regions and --budget-ms together: a budget plans one method a frame"
                    .into(),
            ));
        }
        self.tiles = Some((width, height));
        Ok(self)
    }

    /// The tiles of a `width` x `height` grid, row-major.
    pub fn tiles_of(&self, width: usize, height: usize) -> Vec<Rect> {
        let Some((tw, th)) = self.tiles else {
            return vec![(0, 0, width, height)];
        };
        let mut out = Vec::new();
        for y in (0..height).step_by(th) {
            for x in (0..width).step_by(tw) {
                out.push((x, y, tw.min(width - x), th.min(height - y)));
            }
        }
        out
    }

    /// Keeps the candidates this stream can feed: with `spikes_only` (a recording without
    /// events) none that reads events, and with `max_planes` (align's windows are that long)
    /// none whose window is longer. Each policy class then chooses among what is left, as the
    /// fit chose ([`Policy::restricted`]). Without events a window's class is pooled over its
    /// [`NO_EVENT_ROWS`] nearest rows ([`Policy::pooled_class`]).
    ///
    /// # Errors
    /// Nothing is left, or a class has no method left; the message names it.
    pub fn restrict(
        mut self,
        spikes_only: bool,
        max_planes: Option<usize>,
    ) -> Result<Auto, InferError> {
        if !spikes_only && max_planes.is_none() {
            return Ok(self);
        }
        let reads_events =
            |c: &Candidate| matches!(&c.engine, Engine::Net(net) if net.reads_events());
        self.candidates.retain(|c| {
            !(spikes_only && reads_events(c)) && max_planes.is_none_or(|m| c.planes <= m)
        });
        let why = || {
            let mut w = Vec::new();
            if spikes_only {
                w.push("spikes only".to_string());
            }
            if let Some(m) = max_planes {
                w.push(format!("windows of {m} planes"));
            }
            w.join(", ")
        };
        if self.candidates.is_empty() || max_planes.is_some_and(|m| m < STATS_PLANES) {
            return Err(InferError::Wiring(format!(
                "auto ({}): no method of the policy can run (the statistics need windows of at \
                 least {STATS_PLANES} planes)",
                why()
            )));
        }
        let names: Vec<String> = self.candidates.iter().map(|c| c.name.clone()).collect();
        self.policy = self
            .policy
            .restricted(|m| names.iter().any(|n| n == m), spikes_only)
            .map_err(|e| InferError::Wiring(format!("auto ({}): {e}", why())))?;
        self.no_events = spikes_only;
        Ok(self)
    }

    /// The planes align must give each window: the longest any candidate reads.
    pub fn window_planes(&self) -> usize {
        self.candidates
            .iter()
            .map(|c| c.planes)
            .max()
            .unwrap_or(STATS_PLANES)
            .max(STATS_PLANES)
    }

    /// Starts over on a new stream: TFSTP's synapses and the counts are reset; the cost
    /// estimates, which describe this machine, are kept.
    pub fn reset(&mut self) {
        for c in &mut self.candidates {
            if let Ok(r) = Representer::new(c.represent.config().clone()) {
                c.represent = r;
            }
        }
        self.stats = AutoStats::default();
        self.previous = None;
    }

    /// The budget in nanoseconds, in budget mode.
    pub fn budget_ns(&self) -> Option<i64> {
        self.budget_ms.map(|b| (b * 1e6).round() as i64)
    }

    /// The counts so far.
    pub fn stats(&self) -> &AutoStats {
        &self.stats
    }

    /// The policy.
    pub fn policy(&self) -> &Policy {
        &self.policy
    }

    /// The current cost estimate of a method, ms.
    pub fn cost_ms(&self, method: &str) -> Option<f64> {
        self.candidates
            .iter()
            .find(|c| c.name == method)
            .map(|c| c.cost_ms)
    }

    fn index(&self, method: &str) -> Option<usize> {
        self.candidates.iter().position(|c| c.name == method)
    }

    /// Which candidate a window gets, and whether TFSTP's upkeep runs: the policy's choice (with
    /// upkeep), or under a budget the most accurate ranked method that fits (TFSTP's cost being
    /// its upkeep), with the upkeep where that fits beside it, else the cheapest candidate
    /// without it (TFSTP then misses this window's planes, counted in its `gaps`). A frame is
    /// planned to [`PLAN_SHARE`] of the budget; the rest absorbs jitter.
    fn pick(&self, row: &crate::policy::Class, spent_ms: f64) -> (usize, bool) {
        let chosen = self.index(&row.method).unwrap_or(0);
        let Some(budget) = self.budget_ms else {
            return (chosen, true);
        };
        let is_stp = |i: usize| matches!(self.candidates[i].engine, Engine::Tfstp);
        let upkeep: f64 = (0..self.candidates.len())
            .filter(|&i| is_stp(i))
            .map(|i| self.candidates[i].cost_ms)
            .sum();
        let left = PLAN_SHARE * budget - spent_ms;
        // A TFSTP choice is its own upkeep.
        let cost = |i: usize| {
            if is_stp(i) {
                upkeep
            } else {
                self.candidates[i].cost_ms
            }
        };
        let fits = row
            .ranked
            .iter()
            .filter_map(|k| self.index(&k.method))
            .find(|&i| cost(i) <= left);
        if let Some(i) = fits {
            return (i, is_stp(i) || upkeep + cost(i) <= left);
        }
        let cheapest = (0..self.candidates.len())
            .filter(|&i| !is_stp(i))
            .min_by(|&a, &b| {
                self.candidates[a]
                    .cost_ms
                    .total_cmp(&self.candidates[b].cost_ms)
            })
            .unwrap_or(chosen);
        (cheapest, false)
    }

    /// The frame of one window.
    ///
    /// # Errors
    /// The window is shorter than a chosen method's (align's `--window-planes` below
    /// [`Self::window_planes`]), has no calibration for a method that needs one, or a network
    /// fails.
    pub fn frame(&mut self, w: &AlignedWindow) -> Result<AutoFrame, InferError> {
        if self.tiles.is_some() {
            return self.frame_regions(w);
        }
        let start = Instant::now();
        let short = |n: usize| too_short(w, n);
        let mut s = choice_stats(w, STATS_PLANES, self.window_planes())
            .ok_or_else(|| short(STATS_PLANES))?;
        let row = if self.no_events {
            s.event_rate = 0.0;
            self.policy.pooled_class(&s, NO_EVENT_ROWS)
        } else {
            self.policy.nearest_class(&s).clone()
        };
        let spent = start.elapsed().as_secs_f64() * 1e3;
        let (i, upkeep) = self.pick(&row, spent);
        let t_upkeep = Instant::now();
        // Feed every TFSTP that is not the choice (its synapses must see every plane), timed:
        // its estimate follows what the upkeep costs here. Spikes alone: events are not copied.
        let mut central = None;
        for k in 0..self.candidates.len() {
            if upkeep && k != i && matches!(self.candidates[k].engine, Engine::Tfstp) {
                let t = Instant::now();
                if central.is_none() {
                    central = w.crop_spikes(STATS_PLANES);
                }
                let central = central.as_ref().ok_or_else(|| short(STATS_PLANES))?;
                let c = &mut self.candidates[k];
                c.represent
                    .represent(RepresentationKind::Stp, central)
                    .map_err(|e| window_error(w, e))?;
                c.update_cost(t.elapsed().as_secs_f64() * 1e3);
            }
        }
        let upkeep_ms = t_upkeep.elapsed().as_secs_f64() * 1e3;
        let t0 = Instant::now();
        let data = self.run_candidate(i, w, central.as_ref(), None)?;
        let c = &mut self.candidates[i];
        let estimate_ms = c.cost_ms;
        let method_ms = t0.elapsed().as_secs_f64() * 1e3;
        c.update_cost(method_ms);
        let method = c.name.clone();
        for (k, c) in self.candidates.iter_mut().enumerate() {
            let fed = upkeep && matches!(c.engine, Engine::Tfstp);
            if k != i && !fed {
                c.forget();
            }
        }
        let total = start.elapsed();
        let compute_ns = i64::try_from(total.as_nanos()).unwrap_or(i64::MAX);
        let late = self
            .budget_ms
            .is_some_and(|b| total.as_secs_f64() * 1e3 > b);
        *self.stats.frames.entry(method.clone()).or_default() += 1;
        *self.stats.compute_ns.entry(method.clone()).or_default() += compute_ns.max(0) as u64;
        self.stats.late += u64::from(late);
        if late {
            tracing::debug!(
                seq = w.seq(),
                method,
                estimate_ms,
                stats_ms = spent,
                upkeep_ms,
                method_ms,
                total_ms = total.as_secs_f64() * 1e3,
                "auto: a frame late"
            );
        }
        Ok(AutoFrame {
            data,
            method,
            compute_ns,
            late,
            regions: Vec::new(),
        })
    }

    /// [`Self::frame`] per region ([`Self::with_regions`]).
    fn frame_regions(&mut self, w: &AlignedWindow) -> Result<AutoFrame, InferError> {
        let start = Instant::now();
        let short = || too_short(w, STATS_PLANES);
        let (gw, gh) = (w.spikes.width, w.spikes.height);
        let central = w.crop_spikes(STATS_PLANES).ok_or_else(short)?;
        let span = w.central(STATS_PLANES).ok_or_else(short)?;
        let tiles = self.tiles_of(gw, gh);
        let (tw, th) = self.tiles.unwrap_or((gw.max(1), gh.max(1)));
        let across = gw.div_ceil(tw);
        // Each tile's events, counted where they lie (one pass, nothing copied), over the
        // statistics' planes and over the longest method's ([`choice_stats`]).
        let wide = self.window_planes();
        let wide_span = w.central(wide).map_or(span.events.clone(), |c| c.events);
        let mut events = vec![0usize; tiles.len()];
        let mut wide_events = vec![0usize; tiles.len()];
        let ev = &w.events;
        for k in wide_span.clone() {
            let (x, y) = (usize::from(ev.x[k]), usize::from(ev.y[k]));
            if x < gw && y < gh {
                let t = (y / th) * across + x / tw;
                wide_events[t] += 1;
                events[t] += usize::from(span.events.contains(&k));
            }
        }
        let wide = if wide_span == span.events {
            STATS_PLANES
        } else {
            wide
        };
        let reuse = !self.no_events
            && self
                .previous
                .as_ref()
                .is_some_and(|p| p.0.dim() == (gh, gw) && p.1.len() == tiles.len());
        let mut chosen = Vec::with_capacity(tiles.len());
        let mut sources = Vec::with_capacity(tiles.len());
        for (k, &(x0, y0, rw, rh)) in tiles.iter().enumerate() {
            let tile = central.region(x0, y0, rw, rh, false).ok_or_else(short)?;
            let mut s = window_stats(&tile);
            if !self.no_events {
                let px = (rw * rh) as f64;
                s.event_rate = (events[k] as f64 / (px * STATS_PLANES as f64))
                    .max(wide_events[k] as f64 / (px * wide as f64));
                s.events = wide_events[k] > 0;
            }
            let class = if self.no_events {
                self.policy.pooled_class(&s, NO_EVENT_ROWS).method
            } else {
                self.policy.nearest_class(&s).method.clone()
            };
            let i = self.index(&class).unwrap_or(0);
            sources.push(i);
            let same = self
                .previous
                .as_ref()
                .is_some_and(|p| p.1.get(k) == Some(&i));
            let settling = matches!(self.candidates[i].engine, Engine::Tfstp);
            chosen.push(if reuse && wide_events[k] == 0 && same && !settling {
                usize::MAX
            } else {
                i
            });
        }
        // Feed every TFSTP not chosen, as a whole-frame choice does.
        for k in 0..self.candidates.len() {
            if !chosen.contains(&k) && matches!(self.candidates[k].engine, Engine::Tfstp) {
                let t = Instant::now();
                let c = &mut self.candidates[k];
                c.represent
                    .represent(RepresentationKind::Stp, &central)
                    .map_err(|e| window_error(w, e))?;
                c.update_cost(t.elapsed().as_secs_f64() * 1e3);
            }
        }
        let mut data = Array2::<f32>::zeros((gh, gw));
        let mut mix: Vec<(String, usize)> = Vec::new();
        let mut methods: Vec<usize> = chosen.clone();
        methods.sort_unstable();
        methods.dedup();
        if let Some((prev, _)) = self.previous.as_ref().filter(|_| reuse) {
            let still: Vec<&Rect> = tiles
                .iter()
                .zip(&chosen)
                .filter(|(_, c)| **c == usize::MAX)
                .map(|(t, _)| t)
                .collect();
            for &&(tx, ty, rw, rh) in &still {
                let at = ndarray::s![ty..ty + rh, tx..tx + rw];
                data.slice_mut(at).assign(&prev.slice(at));
            }
            if !still.is_empty() {
                mix.push((REUSED.to_string(), still.len()));
            }
        }
        for i in methods.into_iter().filter(|&i| i != usize::MAX) {
            let mine: Vec<Rect> = tiles
                .iter()
                .zip(&chosen)
                .filter(|(_, c)| **c == i)
                .map(|(t, _)| *t)
                .collect();
            let x0 = mine.iter().map(|t| t.0).min().unwrap_or(0);
            let y0 = mine.iter().map(|t| t.1).min().unwrap_or(0);
            let x1 = mine.iter().map(|t| t.0 + t.2).max().unwrap_or(gw);
            let y1 = mine.iter().map(|t| t.1 + t.3).max().unwrap_or(gh);
            let rect = match self.candidates[i].engine {
                Engine::Tfstp => (0, 0, gw, gh),
                Engine::Net(_) => {
                    let (ax, ay) = (x0.saturating_sub(NET_MARGIN), y0.saturating_sub(NET_MARGIN));
                    let (bx, by) = ((x1 + NET_MARGIN).min(gw), (y1 + NET_MARGIN).min(gh));
                    (ax, ay, bx - ax, by - ay)
                }
                _ => (x0, y0, x1 - x0, y1 - y0),
            };
            let t = Instant::now();
            let whole = rect == (0, 0, gw, gh);
            let part = self.run_candidate(i, w, Some(&central), (!whole).then_some(rect))?;
            for &(tx, ty, rw, rh) in &mine {
                data.slice_mut(ndarray::s![ty..ty + rh, tx..tx + rw])
                    .assign(&part.slice(ndarray::s![
                        ty - rect.1..ty - rect.1 + rh,
                        tx - rect.0..tx - rect.0 + rw
                    ]));
            }
            // The estimate is of a whole frame: a region's time scaled by its share.
            let share = (rect.2 * rect.3) as f64 / (gw * gh).max(1) as f64;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            if share > 0.0 {
                self.candidates[i].update_cost(ms / share);
            }
            mix.push((self.candidates[i].name.clone(), mine.len()));
        }
        mix.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
        for (m, n) in &mix {
            *self.stats.tiles.entry(m.clone()).or_default() += *n as u64;
        }
        let method = mix
            .iter()
            .map(|(m, _)| m.as_str())
            .collect::<Vec<_>>()
            .join("+");
        self.previous = Some((data.clone(), sources));
        let compute_ns = i64::try_from(start.elapsed().as_nanos()).unwrap_or(i64::MAX);
        *self.stats.frames.entry(method.clone()).or_default() += 1;
        *self.stats.compute_ns.entry(method.clone()).or_default() += compute_ns.max(0) as u64;
        Ok(AutoFrame {
            data,
            method,
            compute_ns,
            late: false,
            regions: mix,
        })
    }

    /// Candidate `i`'s frame of `w` (its planes around the reference plane; the statistics'
    /// crop `central` when it reads those), over `rect` of the grid (its spikes and, for a
    /// network that reads them, events cut to the rectangle) or the whole grid.
    fn run_candidate(
        &mut self,
        i: usize,
        w: &AlignedWindow,
        central: Option<&AlignedWindow>,
        rect: Option<Rect>,
    ) -> Result<Array2<f32>, InferError> {
        let short = |n: usize| too_short(w, n);
        let gain = self.lum_per_rate.or(w.spikes.lum_per_rate);
        let c = &mut self.candidates[i];
        let events = matches!(&c.engine, Engine::Net(net) if net.reads_events());
        // The window it reads: events copied only for a network that reads them.
        let planes: Cow<'_, AlignedWindow> = match central {
            Some(central) if !events && c.planes == STATS_PLANES => Cow::Borrowed(central),
            _ if events => Cow::Owned(w.crop(c.planes).ok_or_else(|| short(c.planes))?),
            _ => Cow::Owned(w.crop_spikes(c.planes).ok_or_else(|| short(c.planes))?),
        };
        let win = match rect {
            Some((x0, y0, rw, rh)) => {
                Cow::Owned(planes.region(x0, y0, rw, rh, events).ok_or_else(|| {
                    window_error(
                        w,
                        format!("region {rw}x{rh} at ({x0}, {y0}) is not in the grid"),
                    )
                })?)
            }
            None => planes,
        };
        let need_gain = || {
            gain.ok_or_else(|| InferError::Window {
                seq: w.seq(),
                what: format!("{} needs a calibration (`lum_per_rate`)", c.name),
            })
        };
        let (hh, ww) = (win.spikes.height, win.spikes.width);
        let mut data = Array2::<f32>::zeros((hh, ww));
        match &mut c.engine {
            Engine::Tfp | Engine::Tfstp => {
                let kind = if matches!(c.engine, Engine::Tfp) {
                    RepresentationKind::Tfp
                } else {
                    RepresentationKind::Stp
                };
                let r = c
                    .represent
                    .represent(kind, &win)
                    .map_err(|e| window_error(w, e))?;
                luminance_from_rate_into(
                    r.data.index_axis(Axis(0), 0),
                    need_gain()?,
                    1.0,
                    data.view_mut(),
                )?;
            }
            Engine::Tfi => {
                let r = c
                    .represent
                    .represent(RepresentationKind::Isi, &win)
                    .map_err(|e| window_error(w, e))?;
                luminance_from_isi_into(
                    r.data.index_axis(Axis(0), 0),
                    need_gain()?,
                    1.0,
                    data.view_mut(),
                )?;
            }
            Engine::Net(net) => {
                let out = net.run_window(&win, &mut c.represent)?;
                let g = match net.output() {
                    LearnedOutput::Rate => need_gain()?,
                    LearnedOutput::Luminance => 1.0,
                };
                luminance_from_rate_into(out.view(), g, 1.0, data.view_mut())?;
            }
        }
        Ok(data)
    }
}

/// A window with fewer than the `n` planes around its reference plane that auto reads.
fn too_short(w: &AlignedWindow, n: usize) -> InferError {
    InferError::Window {
        seq: w.seq(),
        what: format!(
            "{} planes; auto needs {n} around the reference plane (align's --window-planes)",
            w.spikes.n_planes
        ),
    }
}

fn window_error(w: &AlignedWindow, e: impl std::fmt::Display) -> InferError {
    InferError::Window {
        seq: w.seq(),
        what: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_event_camera::{DvsConfig, EventCamera};
    use neuspike_scene::Scene;
    use neuspike_spike_camera::{CameraConfig, SpikeCamera};

    const W: usize = 160;
    const H: usize = 96;

    fn root() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    /// 256-plane windows every 20 planes of a held-out-like scene, with their truth.
    fn windows(light: f64, speed: f64, theta: f64, n: usize) -> Vec<(AlignedWindow, Array2<f32>)> {
        let yaml = format!(
            "width: {W}\nheight: {H}\nseed: 7\nlight_scale: {light}\ntexture: {{ kind: noise, beta: 2.0 }}\n\
             motion: {{ vx_px_s: {speed}, vy_px_s: {} }}\n",
            speed / 3.0
        );
        let scene = Scene::from_yaml_str(&yaml, "auto test", None).expect("scene");
        let mut cam = SpikeCamera::new(
            scene.clone(),
            CameraConfig {
                width: W,
                height: H,
                seed: 3,
                ..CameraConfig::default()
            },
        )
        .expect("camera");
        let planes = 256 + 20 * n;
        let chunk = cam.next_chunk(planes, 0);
        let mut dvs = EventCamera::new(
            scene,
            DvsConfig {
                width: W,
                height: H,
                theta_on: theta,
                theta_off: theta,
                seed: 4,
                ..DvsConfig::default()
            },
            chunk.t_first_ns - chunk.plane_period_ns,
        )
        .expect("dvs");
        let events = dvs.advance_to(chunk.plane_time_ns(planes - 1), 0);
        let all = AlignedWindow {
            t_ref_ns: chunk.plane_time_ns(planes / 2),
            ref_plane: (planes / 2) as u64,
            spikes: chunk,
            events,
        };
        (0..n)
            .map(|k| {
                let c = 128 + 20 * k;
                // A window around plane c: shift the reference of the whole recording, then crop.
                let mut w = all.clone();
                w.ref_plane = c as u64;
                w.t_ref_ns = w.spikes.plane_time_ns(c);
                let w = w.crop(256).expect("fits");
                (w, cam.ground_truth(c as u64))
            })
            .collect()
    }

    fn psnr(a: &Array2<f32>, b: &Array2<f32>) -> f64 {
        let mse = a
            .iter()
            .zip(b)
            .map(|(x, y)| f64::from(x - y).powi(2))
            .sum::<f64>()
            / a.len() as f64;
        10.0 * (1.0 / mse).log10()
    }

    fn shipped(budget_ms: Option<f64>) -> Auto {
        Auto::new(
            &root().join("models/policy.yml"),
            &root().join("models"),
            budget_ms,
            None,
            ConvPath::Auto,
        )
        .expect("the shipped policy loads")
    }

    #[test]
    fn the_shipped_policy_takes_a_cheap_method_when_bright_and_still_and_a_network_when_dark_and_fast()
     {
        let mut auto = shipped(None);
        assert!(auto.window_planes() <= 256, "{}", auto.window_planes());
        for (w, truth) in windows(1.0, 0.0, 0.2, 2) {
            let f = auto.frame(&w).expect("frame");
            assert!(
                f.method.starts_with("tfp") || f.method == "tfstp",
                "{}",
                f.method
            );
            assert!(
                psnr(&f.data, &truth) > 30.0,
                "{}: {}",
                f.method,
                psnr(&f.data, &truth)
            );
        }
        for (w, truth) in windows(0.05, 8_000.0, 0.35, 2) {
            let f = auto.frame(&w).expect("frame");
            assert!(f.method.starts_with("neuspike-"), "{}", f.method);
            // Far above what the cheap methods give in the dark (TFP over 33 planes: ~12 dB).
            assert!(
                psnr(&f.data, &truth) > 20.0,
                "{}: {}",
                f.method,
                psnr(&f.data, &truth)
            );
        }
        let s = auto.stats();
        assert_eq!(s.frames.values().sum::<u64>(), 4);
        assert_eq!(s.late, 0);
    }

    /// Left half of `a`, right half of `b` (the same planes and times): spikes pixel by pixel,
    /// the events of `b` that fall right of the middle, and the truth likewise.
    fn halves(
        a: &(AlignedWindow, Array2<f32>),
        b: &(AlignedWindow, Array2<f32>),
    ) -> (AlignedWindow, Array2<f32>) {
        let mut w = b.0.clone();
        let per = neuspike_schemas::bytes_per_plane(W, H);
        for p in 0..w.spikes.n_planes {
            for y in 0..H {
                for x in 0..W / 2 {
                    let k = p * per * 8 + y * W + x;
                    let bit = (a.0.spikes.bits[k / 8] >> (k % 8)) & 1;
                    w.spikes.bits[k / 8] =
                        (w.spikes.bits[k / 8] & !(1 << (k % 8))) | (bit << (k % 8));
                }
            }
        }
        let right = w.region(W / 2, 0, W - W / 2, H, true).expect("right half");
        w.events.t_ns = right.events.t_ns;
        w.events.x = right.events.x.iter().map(|x| x + (W / 2) as u16).collect();
        w.events.y = right.events.y;
        w.events.polarity = right.events.polarity;
        let mut truth = b.1.clone();
        truth
            .slice_mut(ndarray::s![.., ..W / 2])
            .assign(&a.1.slice(ndarray::s![.., ..W / 2]));
        (w, truth)
    }

    #[test]
    fn per_region_each_half_takes_its_own_method_and_a_still_half_is_reused() {
        // One light level: the two halves share the camera's calibration.
        let bright_still = windows(1.0, 0.0, 0.35, 2);
        let bright_fast = windows(1.0, 8_000.0, 0.35, 2);
        let mut auto = shipped(None).with_regions(40, 48).expect("regions");
        assert_eq!(auto.tiles_of(W, H).len(), 8);
        let left = ndarray::s![.., ..W / 2];
        let right = ndarray::s![.., W / 2..];
        let mut first: Option<Array2<f32>> = None;
        for k in 0..2 {
            let (w, truth) = halves(&bright_still[k], &bright_fast[k]);
            let f = auto.frame(&w).expect("frame");
            let tiles: usize = f.regions.iter().map(|r| r.1).sum();
            assert_eq!(tiles, 8, "{:?}", f.regions);
            let net: usize = f
                .regions
                .iter()
                .filter(|r| r.0.starts_with("neuspike-"))
                .map(|r| r.1)
                .sum();
            assert_eq!(net, 4, "{:?}", f.regions);
            assert!(f.method.contains('+'), "{}", f.method);
            let p = |a: &ndarray::ArrayView2<f32>, b: &ndarray::ArrayView2<f32>| {
                psnr(&a.to_owned(), &b.to_owned())
            };
            let (pl, pr) = (
                p(&f.data.slice(left), &truth.slice(left)),
                p(&f.data.slice(right), &truth.slice(right)),
            );
            // The same floors as each scene alone takes with its own method.
            assert!(pl > 30.0 && pr > 20.0, "{:?}: {pl:.2} / {pr:.2}", f.regions);
            match &first {
                None => {
                    // The first frame has nothing to reuse: the still half takes a cheap method.
                    assert!(
                        f.regions.iter().all(|r| r.0.starts_with("neuspike-")
                            || r.0.starts_with("tfp")
                            || r.0 == "tfstp"),
                        "{:?}",
                        f.regions
                    );
                    first = Some(f.data.clone());
                }
                Some(prev) => {
                    // Not one event in the still half: its tiles keep the last frame's pixels.
                    assert!(
                        f.regions.contains(&(REUSED.to_string(), 4)),
                        "{:?}",
                        f.regions
                    );
                    assert_eq!(f.data.slice(left), prev.slice(left));
                }
            }
        }
        assert_eq!(auto.stats().tiles.values().sum::<u64>(), 16);
        // Regions need a side of at least one pixel, and do not mix with a budget.
        assert!(shipped(None).with_regions(0, 8).is_err());
        let e = shipped(Some(5.0)).with_regions(8, 8).err().expect("budget");
        assert!(e.to_string().contains("--budget-ms"), "{e}");
        // Tiles cover the grid once, the last row and column taking what is left.
        let t = shipped(None)
            .with_regions(50, 40)
            .expect("regions")
            .tiles_of(W, H);
        assert_eq!(t.len(), 4 * 3);
        assert_eq!(t.iter().map(|r| r.2 * r.3).sum::<usize>(), W * H);
        assert_eq!(t[11], (150, 80, 10, 16));
    }

    /// A recording without events, in windows of 128 planes: auto chooses among the methods that
    /// read spikes alone and fit the windows. Without events a scene's speed is unknown, so each
    /// light level takes what wins on average over the speeds: TFP or the spike network in
    /// bright light (TFP wins the still scenes, the network the moving ones), TFSTP or the spike
    /// network in the dark.
    #[test]
    fn restricted_to_spikes_and_short_windows_auto_chooses_among_what_runs() {
        let mut auto = shipped(None)
            .restrict(true, Some(128))
            .expect("the shipped policy has spike methods for every class");
        assert!(auto.window_planes() <= 128, "{}", auto.window_planes());
        for class in &auto.policy().classes {
            assert!(
                !class.method.contains("fused") && !class.method.contains("event"),
                "{}: {}",
                class.class,
                class.method
            );
        }
        let frame = |auto: &mut Auto, w: &AlignedWindow| {
            let mut w = w.crop(128).expect("fits");
            w.events.truncate(0);
            auto.frame(&w).expect("frame")
        };
        // A spike network (the paper's decoder or a `-lite` one, of either width) in `f32` or in
        // 8 bits: the policy ranks them all.
        let spike_net = |m: &str| {
            crate::learned::network_variant(m)
                .0
                .starts_with("neuspike-spike-")
        };
        for (w, truth) in windows(1.0, 0.0, 0.2, 2) {
            let f = frame(&mut auto, &w);
            assert!(
                f.method.starts_with("tfp-") || spike_net(&f.method),
                "{}",
                f.method
            );
            assert!(psnr(&f.data, &truth) > 30.0, "{}", psnr(&f.data, &truth));
        }
        for (w, _) in windows(0.05, 8_000.0, 0.35, 2) {
            let f = frame(&mut auto, &w);
            assert!(spike_net(&f.method) || f.method == "tfstp", "{}", f.method);
            assert!(f.data.iter().all(|v| v.is_finite()));
        }
        // Windows too short for the statistics leave nothing to run.
        let e = shipped(None)
            .restrict(true, Some(20))
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("windows of 20 planes"), "{e}");
    }

    #[test]
    fn under_a_budget_and_a_busy_machine_frames_stay_within_the_deadline() {
        // Another thread keeps a core busy for the whole test.
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let s2 = stop.clone();
        let load = std::thread::spawn(move || {
            let mut x = 1u64;
            while !s2.load(std::sync::atomic::Ordering::Relaxed) {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
            }
            x
        });
        let budget = 5.0;
        let mut auto = shipped(Some(budget));
        let ws = windows(0.05, 8_000.0, 0.35, 6);
        let mut late = 0;
        let mut worst: f64 = 0.0;
        for (w, _) in &ws {
            let f = auto.frame(w).expect("frame");
            // No network fits 5 ms: the dark, fast scene falls back to a spike method.
            assert!(!f.method.starts_with("neuspike-"), "{}", f.method);
            worst = worst.max(f.compute_ns as f64 / 1e6);
            late += usize::from(f.late);
        }
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        load.join().expect("load thread");
        // The stated tolerance: a frame may overrun the deadline by at most half of it (a
        // scheduler's time slice on a loaded machine), and most are on time.
        assert!(
            worst < 1.5 * budget,
            "worst frame {worst:.2} ms against {budget} ms"
        );
        assert!(late <= 1, "{late} of {} frames late", ws.len());
        assert_eq!(auto.budget_ns(), Some(5_000_000));
        // Without the budget, the same windows take a network.
        let mut free = shipped(None);
        assert!(
            free.frame(&ws[0].0)
                .expect("frame")
                .method
                .starts_with("neuspike-")
        );
    }

    /// Under a budget this frame's accuracy comes first: the most accurate ranked method that
    /// fits is taken even where TFSTP's upkeep does not fit beside it (not a worse one that
    /// leaves room for the upkeep), the upkeep runs where it fits, and where nothing fits the
    /// cheapest method runs alone.
    #[test]
    fn under_a_budget_the_most_accurate_method_that_fits_comes_before_tfstps_upkeep() {
        let mut auto = shipped(Some(10.0));
        let class = auto
            .policy()
            .classes
            .iter()
            .find(|c| c.class == "light1-speed0")
            .expect("the bright still class")
            .clone();
        assert_eq!(class.ranked[0].method, "tfp-256");
        fn set(auto: &mut Auto, name: &str, ms: f64) {
            let i = auto.index(name).expect(name);
            auto.candidates[i].cost_ms = ms;
        }
        fn pick(auto: &Auto, class: &crate::policy::Class) -> (String, bool) {
            let (i, upkeep) = auto.pick(class, 0.0);
            (auto.candidates[i].name.clone(), upkeep)
        }
        // 7 ms planned: TFP over 256 planes fits, but not with the upkeep beside it.
        set(&mut auto, "tfstp", 6.5);
        set(&mut auto, "tfp-256", 1.0);
        assert_eq!(pick(&auto, &class), ("tfp-256".into(), false));
        // With room for both, both run.
        set(&mut auto, "tfstp", 2.0);
        assert_eq!(pick(&auto, &class), ("tfp-256".into(), true));
        // One slow run rules it out at once; frames that do not run it bring it back.
        set(&mut auto, "tfp-256", 50.0);
        assert_ne!(pick(&auto, &class).0, "tfp-256");
        let i = auto.index("tfp-256").expect("tfp-256");
        let prior = auto.candidates[i].prior_ms;
        assert!(prior < 5.0, "{prior}");
        for _ in 0..60 {
            auto.candidates[i].forget();
        }
        assert!(auto.candidates[i].cost_ms < prior + 0.1);
        assert!(auto.candidates[i].cost_ms >= prior);
        assert_eq!(pick(&auto, &class).0, "tfp-256");
        // The statistics took the whole plan: the cheapest method, alone.
        let (i, upkeep) = auto.pick(&class, 7.5);
        assert!(!upkeep);
        let cheapest = auto
            .candidates
            .iter()
            .filter(|c| !matches!(c.engine, Engine::Tfstp))
            .map(|c| c.cost_ms)
            .fold(f64::INFINITY, f64::min);
        assert_eq!(auto.candidates[i].cost_ms, cheapest);
    }

    #[test]
    fn a_policy_naming_what_auto_cannot_run_is_refused_by_name() {
        let dir = tempfile::tempdir().expect("tempdir");
        let text = std::fs::read_to_string(root().join("models/policy.yml")).expect("policy");
        let first = Policy::read(&root().join("models/policy.yml"))
            .expect("read")
            .classes[0]
            .method
            .clone();
        // A shipped network in 8 bits runs: its file is the stem's.
        let p = dir.path().join("int8.yml");
        std::fs::write(
            &p,
            text.replacen(
                &format!("method: {first}"),
                "method: neuspike-spike-8-int8",
                1,
            ),
        )
        .expect("write");
        Auto::new(&p, &root().join("models"), None, None, ConvPath::Auto)
            .expect("an 8-bit variant of a shipped network");
        for (bad, want) in [
            ("fusion", "fusion"),
            ("neuspike-missing-4", "neuspike-missing-4"),
            ("neuspike-missing-4-int8", "neuspike-missing-4-int8"),
        ] {
            let p = dir.path().join("p.yml");
            std::fs::write(
                &p,
                text.replacen(&format!("method: {first}"), &format!("method: {bad}"), 1),
            )
            .expect("write");
            let e = Auto::new(&p, &root().join("models"), None, None, ConvPath::Auto)
                .err()
                .expect("refused")
                .to_string();
            assert!(
                e.contains(want) && e.contains("not installed") && e.contains("p.yml"),
                "{e}"
            );
        }
        let e = Auto::new(
            &root().join("models/policy.yml"),
            &root().join("models"),
            Some(0.0),
            None,
            ConvPath::Auto,
        )
        .err()
        .expect("zero budget")
        .to_string();
        assert!(e.contains("budget-ms"), "{e}");
        // A window too short for the 33 central planes is an error naming the planes.
        let mut auto = shipped(None);
        let (w, _) = windows(1.0, 0.0, 0.2, 1).remove(0);
        let short = w.crop(9).expect("crop");
        let e = auto.frame(&short).expect_err("short").to_string();
        assert!(
            e.contains("9 planes") && e.contains("--window-planes"),
            "{e}"
        );
    }
}
