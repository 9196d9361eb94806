//! Puts the spike and event streams on one clock and cuts them into aligned windows.
//!
//! Window geometry: a window of `N` planes around reference plane `c` holds planes
//! `c - N/2 ..= c + (N - 1 - N/2)` (33 planes: 16 either side; 32 planes: 16 before, 15 after).
//! Reference planes are the multiples of the stride `K` whose window starts at or after plane 0,
//! so a simulator that emits ground truth at every `K`-th plane has a truth for every window.
//! With `--fps F` instead, the reference instants are `i / F` seconds after plane 0, each snapped
//! to the nearest plane (`F` may not exceed the plane rate).
//! Plane `k` carries the light of `(t_k - T, t_k]`, so the window's events are those of
//! `[t_first - T, t_last)` on the spike clock, where an event's spike-clock time is its own
//! time plus `event_offset_ns`.
//!
//! **Two sensors of different sizes.** With `--homography H` the event camera is another sensor
//! (a DVS beside the spike camera, behind a beam splitter). Each spike pixel takes the events of
//! the event pixel its centre falls in through `H^-1`: a coarser DVS (a DAVIS346 beside a Vidar)
//! gives its events to every spike pixel it covers, leaving none without, and a finer one gives
//! each spike pixel one event pixel's events, not the sum of several. So every spike pixel sees
//! the log-intensity changes of one place, as the event methods that integrate them need. Events
//! of event pixels no spike pixel falls in are dropped and counted. Events that come before the
//! first spike chunk (which gives the grid's size) wait for it. Without a homography,
//! `--estimate-rig-planes N` holds the first `N` planes and the events over them, estimates the
//! homography and the clock offset from them ([`rig::estimate`]), and then aligns everything.
//!
//! A window is emitted once its last plane has arrived and (when the graph has an event camera)
//! the event batches cover its whole interval. At end of stream the windows whose planes all
//! arrived are flushed; a window whose planes never arrived is not counted as produced.
#![deny(missing_docs)]

use std::collections::VecDeque;

pub mod rig;
mod stage;

pub use stage::AlignStage;

use neuspike_geometry::Homography;
use neuspike_schemas::{AlignedWindow, Event, EventBatch, SpikeChunk, bytes_per_plane};

/// Aligner settings. Every field is a node argument in the graph YAML.
#[derive(Clone, Debug, clap::Args)]
pub struct AlignConfig {
    /// Planes per window (N).
    #[arg(long, default_value_t = 33, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub window_planes: u32,
    /// Planes between two reference planes (K): one window every K planes (at most 2^32).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1 << 32))]
    pub stride_planes: u64,
    /// Emit windows at this frame rate (Hz) instead of every `stride-planes` planes.
    #[arg(long)]
    pub fps: Option<f64>,
    /// Added to event timestamps to put them on the spike clock, nanoseconds.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub event_offset_ns: i64,
    /// The homography from the event camera's pixels to the spike camera's, nine numbers
    /// row-major (`h11,h12,...,h33`), when the two sensors differ: events are mapped onto the
    /// spike grid.
    #[arg(long, value_parser = parse_homography, allow_hyphen_values = true)]
    pub homography: Option<Homography>,
    /// Without `--homography`: estimate the homography and the clock offset from the first this
    /// many spike planes and the events over them (`rig::estimate`; the scene must move in more
    /// ways than a steady pan), then align everything with them. Windows start once they are
    /// known.
    #[arg(long)]
    pub estimate_rig_planes: Option<u32>,
    /// The clock offsets `--estimate-rig-planes` searches, either way, nanoseconds.
    #[arg(long, default_value_t = 5_000_000)]
    pub estimate_max_offset_ns: i64,
    /// The most planes a chunk may skip (planes lost on the way) and still continue the
    /// stream, the windows that needed them counted as skipped. A chunk further ahead is
    /// refused and counted, unless it is the last of a run of chunks continuing one another
    /// out there (the camera renumbered its planes), where the stream restarts (2^24: 7 minutes
    /// at 40 kHz).
    #[arg(long, default_value_t = DEFAULT_MAX_GAP_PLANES)]
    pub max_gap_planes: u64,
}

/// The default `--max-gap-planes`.
pub const DEFAULT_MAX_GAP_PLANES: u64 = 1 << 24;

/// Chunks in a row, each continuing the last, beyond `--max-gap-planes` after which align takes
/// the stream to have been renumbered and restarts there.
pub const RESYNC_CHUNKS: u64 = 4;

/// `--homography`'s parser: the error names the value.
fn parse_homography(text: &str) -> Result<Homography, String> {
    Homography::parse(text).map_err(|e| e.to_string())
}

impl Default for AlignConfig {
    fn default() -> Self {
        AlignConfig {
            window_planes: 33,
            stride_planes: 20,
            fps: None,
            event_offset_ns: 0,
            homography: None,
            estimate_rig_planes: None,
            estimate_max_offset_ns: 5_000_000,
            max_gap_planes: DEFAULT_MAX_GAP_PLANES,
        }
    }
}

/// An input that cannot be aligned; the message names what and the values.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AlignError {
    /// The requested frame rate cannot be served by the stream.
    #[error("align: `fps` = {fps} is invalid: {why}")]
    FrameRate {
        /// The requested rate.
        fps: f64,
        /// What is wrong.
        why: String,
    },
    /// The rig could not be estimated (`--estimate-rig-planes`).
    #[error("align: --estimate-rig-planes: {0}")]
    Rig(String),
    /// A chunk's geometry differs from the stream's.
    #[error("spike chunk {seq}: geometry {got} differs from the stream's {expected}")]
    Geometry {
        /// The chunk's sequence number.
        seq: u64,
        /// Geometry found.
        got: String,
        /// Geometry of the stream.
        expected: String,
    },
}

/// Cuts the two streams into windows.
#[derive(Debug)]
pub struct Aligner {
    cfg: AlignConfig,
    before: u64,
    after: u64,
    /// Geometry of the spike stream, from the first chunk: width, height, period, t of plane 0.
    geometry: Option<(usize, usize, i64, i64)>,
    lum_per_rate: Option<f64>,
    /// Buffered planes, contiguous from `first_buffered`.
    planes: VecDeque<Vec<u8>>,
    first_buffered: u64,
    /// Index of the next window in the sequence of reference instants (skipped ones included).
    ref_index: u64,
    next_ref: u64,
    events: EventBatch,
    events_cover_until_ns: i64,
    event_size: (usize, usize),
    spikes_closed: bool,
    events_closed: bool,
    emitted: u64,
    skipped_windows: u64,
    /// The event stream output: whether it is wanted, and where the last batch ended.
    with_stream: bool,
    stream_cut_ns: Option<i64>,
    stream: VecDeque<EventBatch>,
    /// Event batches waiting for the spike grid (with a homography, before the first chunk).
    pending: Vec<EventBatch>,
    /// Events mapped outside the spike grid.
    dropped_events: u64,
    /// With a homography: the spike pixels each event pixel feeds.
    pixel_map: Option<PixelMap>,
    /// With `--estimate-rig-planes`: what is held until the rig is known.
    estimating: Option<Estimating>,
    /// The rig estimate's failure, until taken.
    rig_error: Option<AlignError>,
    /// A run of chunks beyond `--max-gap-planes`: the plane the next would start at, and its
    /// length.
    far: Option<(u64, u64)>,
    /// Chunks refused for starting too far ahead.
    refused_chunks: u64,
}

/// The streams' beginnings, held while the rig is estimated from them.
#[derive(Debug, Default)]
struct Estimating {
    chunks: Vec<SpikeChunk>,
    batches: Vec<EventBatch>,
    planes: usize,
    /// End of the events held, on the event camera's clock.
    events_until_ns: i64,
}

/// The spike pixels each event pixel's events go to: spike pixel `(u, v)` takes event pixel
/// `H^-1 (u + 1/2, v + 1/2)`'s (rounded down), so each spike pixel has at most one event pixel
/// and an event pixel any number of spike pixels. Laid out as compressed rows.
#[derive(Debug)]
struct PixelMap {
    /// Event sensor and spike grid sizes it was made for.
    event_size: (usize, usize),
    grid: (usize, usize),
    /// Event pixel `i`'s spike pixels are `spike[start[i]..start[i + 1]]`.
    start: Vec<u32>,
    spike: Vec<(u16, u16)>,
}

impl PixelMap {
    fn new(h: &Homography, grid: (usize, usize), event_size: (usize, usize)) -> PixelMap {
        let (ew, eh) = event_size;
        let inverse = h.inverse();
        let owner = |u: usize, v: usize| {
            inverse
                .pixel(u as u32, v as u32, ew, eh)
                .map(|(x, y)| y * ew + x)
        };
        let mut count = vec![0u32; ew * eh + 1];
        for v in 0..grid.1 {
            for u in 0..grid.0 {
                if let Some(i) = owner(u, v) {
                    count[i + 1] += 1;
                }
            }
        }
        for i in 0..ew * eh {
            count[i + 1] += count[i];
        }
        let start = count.clone();
        let mut spike = vec![(0u16, 0u16); start[ew * eh] as usize];
        let mut next = count;
        for v in 0..grid.1 {
            for u in 0..grid.0 {
                if let Some(i) = owner(u, v) {
                    // The grid is at most 65535 wide and high (a SpikeChunk's bound).
                    spike[next[i] as usize] = (u as u16, v as u16);
                    next[i] += 1;
                }
            }
        }
        PixelMap {
            event_size,
            grid,
            start,
            spike,
        }
    }

    /// The spike pixels event pixel `(x, y)` feeds (none outside the event sensor).
    fn targets(&self, x: u16, y: u16) -> &[(u16, u16)] {
        let (x, y) = (usize::from(x), usize::from(y));
        if x >= self.event_size.0 || y >= self.event_size.1 {
            return &[];
        }
        let i = y * self.event_size.0 + x;
        &self.spike[self.start[i] as usize..self.start[i + 1] as usize]
    }
}

/// Each event of `batch` on the spike clock (its time plus `offset_ns`) and, through
/// `pixel_map`, at every spike pixel it feeds (at its own pixel without one), handed to `out`.
/// Returns the events that fed no spike pixel.
fn map_events(
    batch: &EventBatch,
    pixel_map: Option<&PixelMap>,
    offset_ns: i64,
    mut out: impl FnMut(Event),
) -> u64 {
    let mut dropped = 0;
    for i in 0..batch.len() {
        let mut e = batch.get(i);
        e.t_ns = e.t_ns.saturating_add(offset_ns);
        match pixel_map {
            Some(m) => {
                let targets = m.targets(e.x, e.y);
                if targets.is_empty() {
                    dropped += 1;
                }
                for &(x, y) in targets {
                    (e.x, e.y) = (x, y);
                    out(e);
                }
            }
            None => out(e),
        }
    }
    dropped
}

/// An event camera's batch on a spike grid of `grid` = `(width, height)` pixels, as align puts
/// every batch of a rig: each event through `h` (event pixel -> spike pixel) at every spike
/// pixel it feeds, its time and the batch's span plus `offset_ns` (align's
/// `--event-offset-ns`). With the events that fed no spike pixel (outside the spike frame).
pub fn onto_spike_grid(
    batch: &EventBatch,
    h: &Homography,
    grid: (usize, usize),
    offset_ns: i64,
) -> (EventBatch, u64) {
    let map = PixelMap::new(h, grid, (batch.width, batch.height));
    let mut out = EventBatch::empty(
        grid.0,
        grid.1,
        batch.t_start_ns.saturating_add(offset_ns),
        batch.t_end_ns.saturating_add(offset_ns),
        batch.seq,
    );
    let dropped = map_events(batch, Some(&map), offset_ns, |e| out.push(e));
    (out, dropped)
}

impl Aligner {
    /// An aligner; `with_events` says whether an event stream is connected.
    pub fn new(cfg: AlignConfig, with_events: bool) -> Self {
        let n = u64::from(cfg.window_planes);
        let before = n / 2;
        let after = n - 1 - before;
        let next_ref = before.div_ceil(cfg.stride_planes) * cfg.stride_planes;
        Aligner {
            ref_index: 0,
            cfg,
            before,
            after,
            geometry: None,
            lum_per_rate: None,
            planes: VecDeque::new(),
            first_buffered: 0,
            next_ref,
            events: EventBatch::default(),
            events_cover_until_ns: i64::MIN,
            event_size: (0, 0),
            spikes_closed: false,
            events_closed: !with_events,
            emitted: 0,
            skipped_windows: 0,
            with_stream: false,
            stream_cut_ns: None,
            stream: VecDeque::new(),
            pending: Vec::new(),
            dropped_events: 0,
            pixel_map: None,
            estimating: None,
            rig_error: None,
            far: None,
            refused_chunks: 0,
        }
        .estimating_if_asked(with_events)
    }

    fn estimating_if_asked(mut self, with_events: bool) -> Self {
        if self.cfg.estimate_rig_planes.is_some() && self.cfg.homography.is_none() && with_events {
            self.estimating = Some(Estimating {
                events_until_ns: i64::MIN,
                ..Estimating::default()
            });
        }
        self
    }

    /// The rig this aligner maps events with: the homography and `--event-offset-ns` (given,
    /// or estimated once `--estimate-rig-planes` planes have come).
    pub fn rig(&self) -> (Option<Homography>, i64) {
        (self.cfg.homography, self.cfg.event_offset_ns)
    }

    /// Whether the rig is still being estimated (the streams are held).
    pub fn estimating(&self) -> bool {
        self.estimating.is_some()
    }

    /// Why the rig could not be estimated, once (the streams are then held for good).
    pub fn take_rig_error(&mut self) -> Option<AlignError> {
        self.rig_error.take()
    }

    /// Estimates the rig once enough is held (or, with `force`, from whatever is), then lets
    /// what was held through.
    fn try_estimate(&mut self, force: bool) -> Result<(), AlignError> {
        let Some(est) = &self.estimating else {
            return Ok(());
        };
        let need = self.cfg.estimate_rig_planes.unwrap_or(0) as usize;
        let last_ns = est
            .chunks
            .last()
            .map_or(i64::MIN, |c| c.plane_time_ns(c.n_planes.saturating_sub(1)));
        let covered = est.events_until_ns
            >= last_ns.saturating_add(self.cfg.estimate_max_offset_ns.max(0))
            || self.events_closed;
        if !(force || (est.planes >= need && covered)) {
            return Ok(());
        }
        let Some(est) = self.estimating.take() else {
            return Ok(());
        };
        let (Some(first), Some(batch0)) = (est.chunks.first(), est.batches.first()) else {
            return Err(AlignError::Rig(format!(
                "{} spike chunks and {} event batches came: both are needed",
                est.chunks.len(),
                est.batches.len()
            )));
        };
        // One chunk of the contiguous planes from the first, one batch of every event.
        let per = bytes_per_plane(first.width, first.height);
        let mut spikes = SpikeChunk {
            bits: Vec::new(),
            n_planes: 0,
            ..first.clone()
        };
        for c in &est.chunks {
            if c.first_plane != spikes.first_plane + spikes.n_planes as u64
                || (c.width, c.height) != (first.width, first.height)
            {
                break;
            }
            spikes
                .bits
                .extend_from_slice(c.bits.get(..c.n_planes * per).unwrap_or(&[]));
            spikes.n_planes += c.n_planes;
        }
        let mut events = EventBatch::empty(
            batch0.width,
            batch0.height,
            batch0.t_start_ns,
            est.events_until_ns,
            0,
        );
        for b in &est.batches {
            for i in 0..b.len() {
                events.push(b.get(i));
            }
        }
        // From the sensors' sizes: the same view, the frames' centres together.
        let k = first.width as f64 / batch0.width.max(1) as f64;
        let init = Homography::scale_translate(
            k,
            k,
            first.width as f64 / 2.0 - batch0.width as f64 / 2.0 * k,
            first.height as f64 / 2.0 - batch0.height as f64 / 2.0 * k,
        )
        .map_err(|e| AlignError::Rig(e.to_string()))?;
        let found = rig::estimate(
            &spikes,
            &events,
            init,
            rig::Clock::Within(self.cfg.estimate_max_offset_ns.max(0)),
        )
        .map_err(|e| AlignError::Rig(format!("{e} (from {} planes)", spikes.n_planes)))?;
        tracing::info!(
            homography = %found.homography,
            event_offset_ns = -found.offset_ns,
            score = found.score,
            events = found.events,
            planes = spikes.n_planes,
            clock = %found.clock,
            "align: the rig estimated"
        );
        if let rig::ClockSource::Searched(_) = found.clock {
            tracing::warn!("align: the rig's clock offset is {}", found.clock);
        }
        self.cfg.homography = Some(found.homography);
        self.cfg.event_offset_ns = found.offset_ns.saturating_neg();
        for c in est.chunks {
            self.push_spikes(c)?;
        }
        for b in est.batches {
            self.push_events(b);
        }
        Ok(())
    }

    /// Events the homography mapped outside the spike grid (dropped).
    pub fn dropped_events(&self) -> u64 {
        self.dropped_events
    }

    /// Also cut the event stream at every window's reference instant: after each window,
    /// [`Aligner::pop_stream`] gives the events of `[previous cut, t_ref)` on the spike clock,
    /// each event exactly once, with the window's sequence number (the first batch starts at the
    /// first window's start, or at the first event before it). The filters of the `infer` node
    /// (HF, complementary, physics fusion) take this stream.
    pub fn with_event_stream(mut self) -> Self {
        self.with_stream = true;
        self
    }

    /// Whether the event stream is cut (see [`Aligner::with_event_stream`]).
    pub fn streams_events(&self) -> bool {
        self.with_stream
    }

    /// The next batch of the event stream (see [`Aligner::with_event_stream`]), in window order.
    pub fn pop_stream(&mut self) -> Option<EventBatch> {
        self.stream.pop_front()
    }

    /// The reference plane of window `i` of the sequence, given the plane period.
    fn ref_plane(&self, i: u64, period_ns: i64) -> u64 {
        match self.cfg.fps {
            Some(fps) => ((i as f64) * 1e9 / fps / period_ns as f64).round() as u64,
            None => {
                let k = self.cfg.stride_planes;
                self.before.div_ceil(k) * k + i * k
            }
        }
    }

    /// Moves to the next reference plane.
    fn advance(&mut self) {
        let period = self.geometry.map_or(1, |g| g.2);
        self.ref_index += 1;
        self.next_ref = self.ref_plane(self.ref_index, period);
    }

    /// Moves to the first reference plane whose window starts at or after `first_plane`
    /// (staying put if the next one does), in a few steps whatever the distance; returns the
    /// windows passed over.
    fn skip_to(&mut self, first_plane: u64) -> u64 {
        let period = self.geometry.map_or(1, |g| g.2).max(1);
        let target = first_plane.saturating_add(self.before);
        let from = self.ref_index;
        // An estimate of the index from below, then steps to the exact one.
        let estimate = match self.cfg.fps {
            Some(fps) => ((target as f64) * period as f64 * fps / 1e9).floor() as u64,
            None => {
                let k = self.cfg.stride_planes.max(1);
                target.saturating_sub(self.before.div_ceil(k) * k) / k
            }
        }
        .saturating_sub(1);
        if estimate > self.ref_index {
            self.ref_index = estimate;
            self.next_ref = self.ref_plane(self.ref_index, period);
        }
        while self.next_ref < target {
            self.advance();
        }
        self.ref_index - from
    }

    /// Chunks refused for starting more than `--max-gap-planes` ahead of the stream.
    pub fn refused_chunks(&self) -> u64 {
        self.refused_chunks
    }

    /// The sequence number of the next window: its place among the stream's windows, those
    /// skipped for missing planes included, so that consumers count a skipped window as missing.
    pub fn next_seq(&self) -> u64 {
        self.emitted + self.skipped_windows
    }

    /// Windows emitted so far.
    pub fn emitted(&self) -> u64 {
        self.emitted
    }

    /// Windows that could not be built because planes were missing.
    pub fn skipped_windows(&self) -> u64 {
        self.skipped_windows
    }

    fn plane_time(&self, k: u64) -> i64 {
        let (_, _, period, t0) = self.geometry.unwrap_or((0, 0, 0, 0));
        t0.saturating_add((k as i64).saturating_mul(period))
    }

    /// Adds a spike chunk; call [`Aligner::pop_ready`] until it returns `None` after each push.
    /// A chunk after a gap (lost planes) restarts the buffer there; windows
    /// that needed the lost planes are skipped and counted.
    pub fn push_spikes(&mut self, chunk: SpikeChunk) -> Result<(), AlignError> {
        if let Some(e) = self.rig_error.take() {
            return Err(e);
        }
        if let Some(est) = &mut self.estimating {
            est.planes += chunk.n_planes;
            est.chunks.push(chunk);
            return self.try_estimate(false);
        }
        let geo = (chunk.width, chunk.height, chunk.plane_period_ns);
        match self.geometry {
            None => {
                if let Some(fps) = self.cfg.fps {
                    let rate = 1e9 / chunk.plane_period_ns as f64;
                    if !(fps.is_finite() && fps > 0.0 && fps <= rate) {
                        return Err(AlignError::FrameRate {
                            fps,
                            why: format!("must be > 0 and at most the plane rate {rate} Hz"),
                        });
                    }
                }
                let t0 = chunk.t_first_ns - (chunk.first_plane as i64) * chunk.plane_period_ns;
                self.geometry = Some((geo.0, geo.1, geo.2, t0));
                self.first_buffered = chunk.first_plane;
                self.lum_per_rate = chunk.lum_per_rate;
                self.next_ref = self.ref_plane(0, chunk.plane_period_ns);
                // The first window whose planes can still come: a stream may start anywhere
                // (a recording played from its middle).
                self.skip_to(chunk.first_plane);
                for batch in std::mem::take(&mut self.pending) {
                    self.add_events(batch);
                }
            }
            Some((w, h, p, _)) if (w, h, p) != geo => {
                return Err(AlignError::Geometry {
                    seq: chunk.seq,
                    got: format!("{}x{} every {} ns", geo.0, geo.1, geo.2),
                    expected: format!("{w}x{h} every {p} ns"),
                });
            }
            Some(_) => {}
        }
        let end = self.first_buffered + self.planes.len() as u64;
        if chunk.first_plane > end && chunk.first_plane - end > self.cfg.max_gap_planes {
            let after = chunk.first_plane.saturating_add(chunk.n_planes as u64);
            let run = match self.far {
                Some((next, n)) if next == chunk.first_plane => n + 1,
                _ => 1,
            };
            if run < RESYNC_CHUNKS {
                self.far = Some((after, run));
                self.refused_chunks += 1;
                tracing::warn!(
                    seq = chunk.seq,
                    expected = end,
                    first_plane = chunk.first_plane,
                    "a spike chunk far past the stream's planes (--max-gap-planes): refused"
                );
                return Ok(());
            }
            // The camera renumbered its planes: the stream goes on from here, its windows
            // numbered on as if nothing were skipped (nothing was lost: the numbering moved).
            tracing::warn!(
                from = end,
                to = chunk.first_plane,
                "the spike stream was renumbered: restarting the window buffer there"
            );
            self.far = None;
            self.planes.clear();
            self.first_buffered = chunk.first_plane;
            self.skip_to(chunk.first_plane);
        } else if chunk.first_plane > end {
            tracing::warn!(
                from = end,
                to = chunk.first_plane,
                "spike planes missing; restarting the window buffer"
            );
            self.far = None;
            self.planes.clear();
            self.first_buffered = chunk.first_plane;
            self.skipped_windows += self.skip_to(chunk.first_plane);
        } else {
            self.far = None;
        }
        let per = bytes_per_plane(chunk.width, chunk.height);
        for (i, plane) in chunk.bits.chunks_exact(per.max(1)).enumerate() {
            let k = chunk.first_plane + i as u64;
            if k >= self.first_buffered + self.planes.len() as u64 {
                self.planes.push_back(plane.to_vec());
            }
        }
        Ok(())
    }

    /// Adds an event batch (its timestamps are shifted onto the spike clock and, with a
    /// homography, its pixels mapped onto the spike grid).
    pub fn push_events(&mut self, batch: EventBatch) {
        if let Some(est) = &mut self.estimating {
            est.events_until_ns = est.events_until_ns.max(batch.t_end_ns);
            est.batches.push(batch);
            if let Err(e) = self.try_estimate(false) {
                self.rig_error = Some(e);
            }
            return;
        }
        if self.cfg.homography.is_some() && self.geometry.is_none() {
            self.pending.push(batch);
            return;
        }
        self.add_events(batch);
    }

    fn add_events(&mut self, batch: EventBatch) {
        let off = self.cfg.event_offset_ns;
        let grid = self.geometry.map(|g| (g.0, g.1));
        let map = self.cfg.homography.zip(grid);
        self.event_size = grid
            .filter(|_| map.is_some())
            .unwrap_or((batch.width, batch.height));
        if let Some((h, grid)) = map {
            let size = (batch.width, batch.height);
            if self
                .pixel_map
                .as_ref()
                .is_none_or(|m| m.event_size != size || m.grid != grid)
            {
                self.pixel_map = Some(PixelMap::new(&h, grid, size));
            }
        }
        let pixel_map = map.and(self.pixel_map.as_ref());
        let events = &mut self.events;
        self.dropped_events += map_events(&batch, pixel_map, off, |e| events.push(e));
        self.events_cover_until_ns = self
            .events_cover_until_ns
            .max(batch.t_end_ns.saturating_add(off));
    }

    /// No more spikes will come (a rig being estimated is estimated from what came).
    pub fn close_spikes(&mut self) {
        self.spikes_closed = true;
        if let Err(e) = self.try_estimate(true) {
            self.rig_error = Some(e);
        }
    }

    /// No more events will come.
    pub fn close_events(&mut self) {
        self.events_closed = true;
        if let Err(e) = self.try_estimate(false) {
            self.rig_error = Some(e);
        }
    }

    /// Whether no further window can ever be emitted.
    pub fn finished(&self) -> bool {
        self.spikes_closed && !self.has_planes_for(self.next_ref)
    }

    fn has_planes_for(&self, c: u64) -> bool {
        let last = c + self.after;
        self.geometry.is_some()
            && c >= self.before
            && c - self.before >= self.first_buffered
            && last < self.first_buffered + self.planes.len() as u64
    }

    /// The next window, if everything it needs has arrived.
    pub fn pop_ready(&mut self) -> Option<AlignedWindow> {
        let c = self.next_ref;
        if !self.has_planes_for(c) {
            return None;
        }
        let (w, h, period, _) = self.geometry?;
        let first = c - self.before;
        let last = c + self.after;
        let t_start = self.plane_time(first) - period;
        let t_end = self.plane_time(last);
        if !self.events_closed && self.events_cover_until_ns < t_end {
            return None;
        }
        let n = (last - first + 1) as usize;
        let offset = (first - self.first_buffered) as usize;
        let mut bits = Vec::with_capacity(n * bytes_per_plane(w, h));
        for p in self.planes.range(offset..offset + n) {
            bits.extend_from_slice(p);
        }
        let events = self.buffered_events(t_start, t_end);
        if self.with_stream {
            let t_ref = self.plane_time(c);
            let from = match self.stream_cut_ns {
                Some(cut) => cut,
                None => self
                    .events
                    .t_ns
                    .first()
                    .map_or(t_start, |&t| t.min(t_start)),
            };
            let batch = self.buffered_events(from, t_ref);
            self.stream_cut_ns = Some(t_ref);
            self.stream.push_back(batch);
        }
        let window = AlignedWindow {
            t_ref_ns: self.plane_time(c),
            ref_plane: c,
            spikes: SpikeChunk {
                width: w,
                height: h,
                first_plane: first,
                n_planes: n,
                t_first_ns: self.plane_time(first),
                plane_period_ns: period,
                seq: self.next_seq(),
                bits,
                lum_per_rate: self.lum_per_rate,
            },
            events,
        };
        self.emitted += 1;
        self.advance();
        self.drop_consumed();
        Some(window)
    }

    /// The buffered events of `[t_start, t_end)` as a batch numbered like the next window.
    fn buffered_events(&self, t_start: i64, t_end: i64) -> EventBatch {
        let lo = self.events.t_ns.partition_point(|&t| t < t_start);
        let hi = self.events.t_ns.partition_point(|&t| t < t_end);
        let (w, h) = self.event_size;
        let mut batch = EventBatch::empty(w, h, t_start, t_end, self.next_seq());
        batch.t_ns.extend_from_slice(&self.events.t_ns[lo..hi]);
        batch.x.extend_from_slice(&self.events.x[lo..hi]);
        batch.y.extend_from_slice(&self.events.y[lo..hi]);
        batch
            .polarity
            .extend_from_slice(&self.events.polarity[lo..hi]);
        batch
    }

    /// Forgets planes and events no later window needs.
    fn drop_consumed(&mut self) {
        let keep_from = self.next_ref.saturating_sub(self.before);
        while self.first_buffered < keep_from && !self.planes.is_empty() {
            self.planes.pop_front();
            self.first_buffered += 1;
        }
        if self.planes.is_empty() {
            self.first_buffered = self.first_buffered.max(keep_from);
        }
        let (_, _, period, _) = self.geometry.unwrap_or((0, 0, 0, 0));
        let mut t_keep = self.plane_time(keep_from) - period;
        if let Some(cut) = self.stream_cut_ns {
            t_keep = t_keep.min(cut); // the stream's next batch starts at the cut
        }
        let cut = self.events.t_ns.partition_point(|&t| t < t_keep);
        if cut > 0 {
            self.events.t_ns.drain(..cut);
            self.events.x.drain(..cut);
            self.events.y.drain(..cut);
            self.events.polarity.drain(..cut);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_schemas::Event;

    const P: i64 = 50_000;

    fn chunk(first: u64, n: usize, seq: u64) -> SpikeChunk {
        // Plane k has all bits set to (k % 256) so tests can tell planes apart.
        let per = bytes_per_plane(4, 2);
        let bits = (0..n)
            .flat_map(|i| vec![((first + i as u64) % 256) as u8; per])
            .collect();
        SpikeChunk {
            width: 4,
            height: 2,
            first_plane: first,
            n_planes: n,
            t_first_ns: first as i64 * P,
            plane_period_ns: P,
            seq,
            bits,
            lum_per_rate: Some(1.0),
        }
    }

    #[test]
    fn a_homography_maps_events_onto_the_spike_grid_and_drops_what_falls_outside() {
        // An 8x4 event sensor at half the spike camera's pitch, shifted one spike pixel left:
        // event pixel (x, y) lands at ((x + 0.5) / 2 - 1, (y + 0.5) / 2), so spike pixel (u, v)
        // takes event pixel (2u + 3, 2v + 1): one of the four it overlaps, not their sum.
        let h = Homography::scale_translate(0.5, 0.5, -1.0, 0.0).unwrap();
        let cfg = AlignConfig {
            window_planes: 3,
            stride_planes: 2,
            homography: Some(h),
            ..Default::default()
        };
        let mut a = Aligner::new(cfg, true);
        let mut b = EventBatch::empty(8, 4, 0, 10 * P, 0);
        for (x, y) in [(0u16, 0u16), (1, 0), (3, 1), (7, 3), (5, 2), (9, 1)] {
            b.push(Event {
                t_ns: P,
                x,
                y,
                polarity: 1,
            });
        }
        // Events first: they wait for the grid.
        a.push_events(b);
        a.close_events();
        a.push_spikes(chunk(0, 6, 0)).unwrap();
        let w = a.pop_ready().expect("window");
        assert_eq!((w.events.width, w.events.height), (4, 2));
        let got: Vec<(u16, u16)> = (0..w.events.len())
            .map(|i| (w.events.get(i).x, w.events.get(i).y))
            .collect();
        // (0,0), (1,0) and (5,2) are no spike pixel's; (9,1) is off the event sensor.
        assert_eq!(got, vec![(0, 0), (2, 1)]);
        assert_eq!(a.dropped_events(), 4);
        w.events.validate("mapped").unwrap();
    }

    /// `onto_spike_grid` puts a batch where align's windows put it: the same events at the
    /// same spike pixels, the same ones dropped, the times and the span on the spike clock.
    #[test]
    fn onto_spike_grid_maps_as_align_does() {
        let h = Homography::scale_translate(0.5, 0.5, -1.0, 0.0).unwrap();
        let mut b = EventBatch::empty(8, 4, 0, 10 * P, 0);
        for (x, y) in [(0u16, 0u16), (1, 0), (3, 1), (7, 3), (5, 2), (9, 1)] {
            b.push(Event {
                t_ns: P + 7,
                x,
                y,
                polarity: -1,
            });
        }
        let (mapped, dropped) = onto_spike_grid(&b, &h, (4, 2), -7);
        assert_eq!(dropped, 4);
        assert_eq!((mapped.width, mapped.height), (4, 2));
        assert_eq!((mapped.t_start_ns, mapped.t_end_ns), (-7, 10 * P - 7));
        let got: Vec<Event> = (0..mapped.len()).map(|i| mapped.get(i)).collect();
        let at = |x, y| Event {
            t_ns: P,
            x,
            y,
            polarity: -1,
        };
        assert_eq!(got, vec![at(0, 0), at(2, 1)]);
        mapped.validate("mapped").unwrap();
    }

    /// A coarser event sensor (a 3x2 one over a 4x3 grid): every spike pixel takes the events of
    /// the event pixel it lies in, so one event feeds every spike pixel its pixel covers and none
    /// is left without.
    #[test]
    fn a_coarser_event_sensor_feeds_every_spike_pixel_it_covers() {
        let h = Homography::scale_translate(4.0 / 3.0, 1.5, 0.0, 0.0).unwrap();
        let map = PixelMap::new(&h, (4, 3), (3, 2));
        let mut fed = vec![0; 12];
        for y in 0..2u16 {
            for x in 0..3u16 {
                for &(u, v) in map.targets(x, y) {
                    fed[usize::from(v) * 4 + usize::from(u)] += 1;
                }
            }
        }
        assert_eq!(fed, vec![1; 12], "each spike pixel exactly once");
        // Spike columns' centres 0.5, 1.5, 2.5, 3.5 fall in event columns 0, 1, 1, 2; rows' 0.5,
        // 1.5, 2.5 in event rows 0, 1, 1.
        assert_eq!(map.targets(0, 0), &[(0, 0)]);
        assert_eq!(map.targets(1, 0), &[(1, 0), (2, 0)]);
        assert!(map.targets(3, 0).is_empty());
    }

    fn events(t0: i64, t1: i64, at: &[i64]) -> EventBatch {
        let mut b = EventBatch::empty(4, 2, t0, t1, 0);
        for &t in at {
            b.push(Event {
                t_ns: t,
                x: 1,
                y: 1,
                polarity: 1,
            });
        }
        b
    }

    #[test]
    fn event_stream_holds_every_event_once_in_contiguous_batches() {
        // Windows that leave gaps between them (5 planes every 9) and windows that overlap
        // (9 every 2): the stream is the same either way.
        for (window_planes, stride_planes) in [(5, 9), (9, 2)] {
            let cfg = AlignConfig {
                window_planes,
                stride_planes,
                fps: None,
                event_offset_ns: 0,
                homography: None,
                ..Default::default()
            };
            let mut a = Aligner::new(cfg, true).with_event_stream();
            let at: Vec<i64> = (0..400).map(|k| k * 9_999).collect();
            let mut windows = Vec::new();
            let mut stream = Vec::new();
            for i in 0..8u64 {
                a.push_spikes(chunk(i * 10, 10, i)).unwrap();
                let (t0, t1) = (i as i64 * 10 * P, (i as i64 + 1) * 10 * P);
                let inside: Vec<i64> = at.iter().copied().filter(|&t| t >= t0 && t < t1).collect();
                a.push_events(events(t0, t1, &inside));
                while let Some(w) = a.pop_ready() {
                    windows.push(w);
                    stream.push(a.pop_stream().expect("a batch per window"));
                }
            }
            assert!(windows.len() >= 3, "{window_planes}/{stride_planes}");
            let mut all = Vec::new();
            for (k, (w, b)) in windows.iter().zip(&stream).enumerate() {
                assert_eq!(b.seq, w.seq(), "batch {k} carries its window's seq");
                assert_eq!(b.t_end_ns, w.t_ref_ns, "batch {k} ends at t_ref");
                if k > 0 {
                    assert_eq!(
                        b.t_start_ns,
                        stream[k - 1].t_end_ns,
                        "batch {k} is contiguous"
                    );
                }
                assert!(b.t_ns.iter().all(|&t| t >= b.t_start_ns && t < b.t_end_ns));
                all.extend_from_slice(&b.t_ns);
            }
            let last = windows.last().unwrap().t_ref_ns;
            let expected: Vec<i64> = at.iter().copied().filter(|&t| t < last).collect();
            assert_eq!(all, expected, "{window_planes}/{stride_planes}");
        }
    }

    #[test]
    fn windows_are_centred_on_stride_multiples() {
        let cfg = AlignConfig {
            window_planes: 5,
            stride_planes: 4,
            fps: None,
            event_offset_ns: 0,
            homography: None,
            ..Default::default()
        };
        let mut a = Aligner::new(cfg, false);
        a.push_spikes(chunk(0, 20, 0)).unwrap();
        let mut refs = vec![];
        while let Some(w) = a.pop_ready() {
            assert_eq!(w.spikes.n_planes, 5);
            assert_eq!(w.spikes.first_plane, w.ref_plane - 2);
            assert_eq!(w.spikes.bits[w.ref_index()], (w.ref_plane % 256) as u8);
            assert_eq!(w.t_ref_ns, w.ref_plane as i64 * P);
            refs.push(w.ref_plane);
        }
        // 4, 8, 12, 16; 0 needs planes before 0, 20 needs plane 22.
        assert_eq!(refs, vec![4, 8, 12, 16]);
        a.close_spikes();
        assert!(a.finished());
    }

    #[test]
    fn a_stream_starting_mid_way_gets_the_windows_its_planes_cover() {
        let cfg = AlignConfig {
            window_planes: 5,
            stride_planes: 4,
            fps: None,
            event_offset_ns: 0,
            homography: None,
            ..Default::default()
        };
        let mut a = Aligner::new(cfg, false);
        a.push_spikes(chunk(1001, 20, 0)).unwrap();
        let mut refs = vec![];
        while let Some(w) = a.pop_ready() {
            assert_eq!(w.spikes.bits[w.ref_index()], (w.ref_plane % 256) as u8);
            assert_eq!(w.t_ref_ns, w.ref_plane as i64 * P);
            refs.push(w.ref_plane);
        }
        // Planes 1001..=1020: 1004 needs 1002..=1006; 1020 would need 1022.
        assert_eq!(refs, vec![1004, 1008, 1012, 1016]);
        assert_eq!(a.skipped_windows(), 0);
    }

    #[test]
    fn waits_for_events_then_slices_them() {
        let cfg = AlignConfig {
            window_planes: 3,
            stride_planes: 10,
            fps: None,
            event_offset_ns: 1_000,
            homography: None,
            ..Default::default()
        };
        let mut a = Aligner::new(cfg, true);
        a.push_spikes(chunk(0, 12, 0)).unwrap();
        // Window c = 10 spans planes 9..=11: events [8P, 11P) on the spike clock.
        assert!(a.pop_ready().is_none(), "must wait for the events");
        a.push_events(events(
            0,
            10 * P,
            &[8 * P - 1_001, 8 * P - 1_000, 10 * P - 1],
        ));
        assert!(
            a.pop_ready().is_none(),
            "events cover only up to 10P + offset"
        );
        a.push_events(events(10 * P, 12 * P, &[11 * P - 1_001, 11 * P - 1_000]));
        let w = a.pop_ready().expect("window");
        assert_eq!(w.ref_plane, 10);
        assert_eq!((w.events.t_start_ns, w.events.t_end_ns), (8 * P, 11 * P));
        assert_eq!(w.events.t_ns, vec![8 * P, 10 * P + 999, 11 * P - 1]);
    }

    #[test]
    fn flushes_at_end_of_stream_without_events() {
        let mut a = Aligner::new(
            AlignConfig {
                window_planes: 3,
                stride_planes: 2,
                fps: None,
                event_offset_ns: 0,
                homography: None,
                ..Default::default()
            },
            true,
        );
        a.push_spikes(chunk(0, 6, 0)).unwrap();
        assert!(a.pop_ready().is_none());
        a.close_events();
        a.close_spikes();
        let n = std::iter::from_fn(|| a.pop_ready()).count();
        assert_eq!(n, 2); // refs 2 and 4; 6 would need plane 7
        assert!(a.finished());
    }

    #[test]
    fn gap_skips_windows_and_counts_them() {
        let mut a = Aligner::new(
            AlignConfig {
                window_planes: 3,
                stride_planes: 2,
                fps: None,
                event_offset_ns: 0,
                homography: None,
                ..Default::default()
            },
            false,
        );
        let mut refs = vec![];
        for c in [chunk(0, 4, 0), chunk(10, 6, 2)] {
            a.push_spikes(c).unwrap();
            refs.extend(std::iter::from_fn(|| a.pop_ready()).map(|w| (w.ref_plane, w.seq())));
        }
        // Windows 4, 6, 8 and 10 needed lost planes: skipped, their numbers left as a gap.
        assert_eq!(refs, vec![(2, 0), (12, 5), (14, 6)]);
        assert_eq!(a.skipped_windows(), 4);
        assert_eq!(a.next_seq(), 7);
    }

    #[test]
    fn frame_rate_mode_snaps_to_the_nearest_plane() {
        // 20 kHz planes (P = 50 us), 3 kHz frames: instants 0, 333.3, 666.7, 1000 us, ... ->
        // planes 0, 7, 13, 20, 27, 33; windows of 5 need 2 planes before: the first is plane 7.
        let cfg = AlignConfig {
            window_planes: 5,
            stride_planes: 1,
            fps: Some(3000.0),
            event_offset_ns: 0,
            homography: None,
            ..Default::default()
        };
        let mut a = Aligner::new(cfg, false);
        a.push_spikes(chunk(0, 36, 0)).unwrap();
        let refs: Vec<u64> = std::iter::from_fn(|| a.pop_ready())
            .map(|w| w.ref_plane)
            .collect();
        assert_eq!(refs, vec![7, 13, 20, 27, 33]);
        let cfg = AlignConfig {
            fps: Some(30_000.0),
            ..AlignConfig::default()
        };
        let e = Aligner::new(cfg, false)
            .push_spikes(chunk(0, 2, 0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("fps") && e.contains("30000") && e.contains("20000"),
            "{e}"
        );
    }

    fn refs_of(a: &mut Aligner) -> Vec<(u64, u64)> {
        std::iter::from_fn(|| a.pop_ready())
            .map(|w| (w.ref_plane, w.seq()))
            .collect()
    }

    #[test]
    fn a_chunk_far_ahead_is_refused_without_stepping_or_blinding_the_stream() {
        let cfg = AlignConfig {
            window_planes: 3,
            stride_planes: 1,
            ..Default::default()
        };
        let mut a = Aligner::new(cfg, false);
        a.push_spikes(chunk(0, 4, 0)).unwrap();
        assert_eq!(refs_of(&mut a), [(1, 0), (2, 1)]);
        // A forged chunk 2^40 planes ahead, with no planes: refused at
        // once (one stride at a time it would take days), nothing counted lost.
        let mut forged = chunk(1 << 40, 0, 1);
        forged.bits.clear();
        let t = std::time::Instant::now();
        a.push_spikes(forged).unwrap();
        assert!(t.elapsed() < std::time::Duration::from_secs(1));
        assert_eq!((a.refused_chunks(), a.skipped_windows()), (1, 0));
        // The genuine planes after it still make their windows.
        a.push_spikes(chunk(4, 2, 2)).unwrap();
        assert_eq!(refs_of(&mut a), [(3, 2), (4, 3)]);
    }

    #[test]
    fn a_long_gap_within_the_limit_is_skipped_in_one_step_and_counted() {
        let cfg = AlignConfig {
            window_planes: 3,
            stride_planes: 1,
            ..Default::default()
        };
        let mut a = Aligner::new(cfg, false);
        a.push_spikes(chunk(0, 3, 0)).unwrap();
        assert_eq!(refs_of(&mut a), [(1, 0)]);
        let gap = DEFAULT_MAX_GAP_PLANES - 1;
        let t = std::time::Instant::now();
        a.push_spikes(chunk(3 + gap, 3, 1)).unwrap();
        assert!(t.elapsed() < std::time::Duration::from_secs(1));
        // Windows 2 ..= gap + 3 needed lost planes; the next is around plane gap + 4.
        let got = refs_of(&mut a);
        assert_eq!(got, [(gap + 4, gap + 3)]);
        assert_eq!(a.skipped_windows(), gap + 2);
    }

    #[test]
    fn a_renumbered_stream_is_followed_after_a_run_of_chunks() {
        let cfg = AlignConfig {
            window_planes: 3,
            stride_planes: 2,
            ..Default::default()
        };
        let mut a = Aligner::new(cfg, false);
        a.push_spikes(chunk(0, 4, 0)).unwrap();
        assert_eq!(refs_of(&mut a), [(2, 0)]);
        let base = 1u64 << 40;
        for k in 0..RESYNC_CHUNKS {
            a.push_spikes(chunk(base + 2 * k, 2, 1 + k)).unwrap();
        }
        // The first three were refused; the fourth restarted the stream there, numbered on.
        assert_eq!(a.refused_chunks(), RESYNC_CHUNKS - 1);
        assert_eq!(a.skipped_windows(), 0);
        a.push_spikes(chunk(base + 2 * RESYNC_CHUNKS, 4, 9))
            .unwrap();
        let got = refs_of(&mut a);
        assert_eq!(got.first(), Some(&(base + 2 * RESYNC_CHUNKS - 2 + 2, 1)));
    }

    #[test]
    fn geometry_change_is_an_error() {
        let mut a = Aligner::new(AlignConfig::default(), false);
        a.push_spikes(chunk(0, 2, 0)).unwrap();
        let mut c = chunk(2, 2, 1);
        c.width = 8;
        c.bits = vec![0; 2 * bytes_per_plane(8, 2)];
        let e = a.push_spikes(c).unwrap_err().to_string();
        assert!(e.contains("8x2") && e.contains("4x2"), "{e}");
    }
}
