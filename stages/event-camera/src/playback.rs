//! The event source's stage: the simulated DVS or an event recording, cut into batches of
//! consecutive half-open intervals `[t_start_ns, t_end_ns)`, empty batches included, so a
//! receiver always knows how far time went.
//!
//! A recording is any file `neuspike_formats::open_events` reads (Event Camera Dataset text,
//! Prophesee RAW EVT 2.0 / 3.0, Prophesee DAT, AEDAT 4; told apart by content). Its batches run
//! from `start_ns` (default: the first event's time) to `end_ns` or the end of the recording (the
//! last event's time + 1 ns), whichever comes first; the last batch is shortened to it. Event
//! times are the recording's own; align's `--event-offset-ns` moves them onto the spike clock.
//! The file is decoded a buffer at a time: memory is bounded by the read buffer and one batch.
//! A recording that turns out bad part-way (corrupt word, step back in time) has every batch
//! before the fault played, the last one ending just after the last good event; then the error,
//! naming the file and the byte offset or line.

use std::path::{Path, PathBuf};

use neuspike_formats::{EventReader, FormatError, ReadOptions, Resolution, open_events, sniff};
use neuspike_scene::{Scene, SceneError};
use neuspike_schemas::EventBatch;
use neuspike_stage::{Flow, Msg, MsgType, Outbox, Pacer, Port, Stage, Tallies};

use crate::{ConfigError, DvsConfig, EventCamera};

/// Events decoded per read from a recording (the read buffer's size).
const READ_EVENTS: usize = 1 << 16;

/// The event source's settings (the node's `args:`).
#[derive(Clone, Debug, clap::Args)]
pub struct EventSourceConfig {
    /// Built-in scene name or path of a scene YAML file.
    #[arg(long, default_value = "bright-slow", conflicts_with = "file")]
    pub scene: String,
    /// Play this event recording (ECD text, Prophesee RAW EVT 2.0/3.0 or DAT, AEDAT 4) instead
    /// of simulating a scene (its size comes from the file or `--file-width`/`--file-height`,
    /// not the simulator's `--width`/`--height`).
    #[arg(long, conflicts_with_all = ["width", "height"])]
    pub file: Option<PathBuf>,
    /// Sensor width of a recording whose header does not state it.
    #[arg(long, requires_all = ["file", "file_height"],
          value_parser = clap::value_parser!(u16).range(1..))]
    pub file_width: Option<u16>,
    /// Sensor height of a recording whose header does not state it.
    #[arg(long, requires_all = ["file", "file_width"],
          value_parser = clap::value_parser!(u16).range(1..))]
    pub file_height: Option<u16>,
    /// Start of the first batch, nanoseconds on the recording's clock (default: the first
    /// event's time); earlier events are skipped.
    #[arg(long, requires = "file", allow_negative_numbers = true)]
    pub start_ns: Option<i64>,
    /// Length of the interval each batch covers, nanoseconds.
    #[arg(long, default_value_t = 1_000_000, value_parser = clap::value_parser!(i64).range(1..))]
    pub batch_ns: i64,
    /// Stop at this time, nanoseconds (default: the scene's duration, or the end of the
    /// recording).
    #[arg(long, allow_negative_numbers = true)]
    pub end_ns: Option<i64>,
    /// The DVS model's settings.
    #[command(flatten)]
    pub camera: DvsConfig,
}

/// Why the event source could not start or could not play to the end.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// A camera setting is out of its domain.
    #[error("event-source: bad camera settings")]
    Config(#[from] ConfigError),
    /// The scene could not be loaded.
    #[error("event-source: cannot load the scene")]
    Scene(#[from] SceneError),
    /// The recording could not be opened (`--file-width` and `--file-height` give the sensor
    /// size of files that do not state it).
    #[error(
        "event-source: cannot play the recording (--file-width and --file-height give the sensor size of files that do not state it)"
    )]
    Open(#[source] FormatError),
    /// The recording failed part-way, after the batches before the fault.
    #[error("event-source: the recording could not be read to its end")]
    Read(#[source] FormatError),
    /// `end-ns` is not after `start-ns`.
    #[error("event-source: `end-ns` = {end_ns} is invalid: must be after `start-ns` = {start_ns}")]
    Interval {
        /// The start asked for.
        start_ns: i64,
        /// The end asked for.
        end_ns: i64,
    },
}

/// One batch and the camera time at which it is complete, from the start of the stream.
#[derive(Debug)]
pub struct EventStep {
    /// The events of `[t_start_ns, t_end_ns)`.
    pub batch: EventBatch,
    /// When the camera has finished the batch, ns from the stream's start.
    pub due_ns: i64,
}

/// Where the events come from.
pub enum EventSource {
    /// The simulated camera looking at a scene.
    Scene(Box<ScenePlayback>),
    /// A recording.
    File(Box<EventFile>),
}

impl EventSource {
    /// Checks the settings and opens the scene or the file, before any message is sent.
    pub fn open(cfg: &EventSourceConfig) -> Result<Self, SourceError> {
        let Some(path) = &cfg.file else {
            let cam = EventCamera::new(Scene::load(&cfg.scene)?, cfg.camera.clone(), 0)?;
            let end_ns = cfg.end_ns.unwrap_or_else(|| cam.scene().duration_ns());
            return Ok(EventSource::Scene(Box::new(ScenePlayback {
                start_ns: cam.time_ns(),
                cam,
                end_ns,
                batch_ns: cfg.batch_ns.max(1),
                seq: 0,
                events: 0,
            })));
        };
        if let (Some(start_ns), Some(end_ns)) = (cfg.start_ns, cfg.end_ns)
            && end_ns <= start_ns
        {
            return Err(SourceError::Interval { start_ns, end_ns });
        }
        let resolution = match (cfg.file_width, cfg.file_height) {
            (Some(w), Some(h)) => Some(Resolution::new(w, h)),
            _ => None,
        };
        let file = EventFile::open(path, resolution, cfg.start_ns, cfg.end_ns, cfg.batch_ns)
            .map_err(SourceError::Open)?;
        Ok(EventSource::File(Box::new(file)))
    }

    /// The next batch, or `None` at the end of the stream. A fault in a recording ends the
    /// stream after every batch before it.
    pub fn next_step(&mut self) -> Result<Option<EventStep>, SourceError> {
        match self {
            EventSource::Scene(s) => Ok(s.next_step()),
            EventSource::File(f) => {
                let batch = f.next_batch().map_err(|e| {
                    tracing::error!("{e}; the stream ends after the events read before it");
                    SourceError::Read(e)
                })?;
                Ok(batch.map(|batch| {
                    let start = f.stream_start_ns.unwrap_or(batch.t_start_ns);
                    EventStep {
                        due_ns: batch.t_end_ns.saturating_sub(start),
                        batch,
                    }
                }))
            }
        }
    }

    /// Logs what is about to be played.
    pub fn log_start(&self) {
        match self {
            EventSource::Scene(s) => tracing::info!(
                end_ns = s.end_ns,
                step_ns = s.cam.step_ns(),
                "event camera started"
            ),
            EventSource::File(f) => tracing::info!(
                file = %f.path.display(),
                start_ns = ?f.start_ns,
                end_ns = ?f.end_ns,
                batch_ns = f.batch_ns,
                "playing an event recording"
            ),
        }
    }

    /// Logs what was played.
    pub fn log_end(&self) {
        match self {
            EventSource::Scene(s) => {
                tracing::info!(batches = s.seq, events = s.events, "event camera finished")
            }
            EventSource::File(f) => {
                let stats = f.reader.stats();
                tracing::info!(
                    batches = f.seq,
                    events = f.events,
                    first_ns = ?f.stream_start_ns,
                    end_ns = ?f.next_start_ns,
                    skipped_before_start = f.skipped_before_start,
                    duplicates = stats.duplicate_events,
                    time_wraps = stats.time_wraps,
                    without_time_base = stats.events_without_time_base,
                    "event recording played"
                );
            }
        }
    }
}

/// The simulated camera, a batch of `batch_ns` at a time up to `end_ns`.
pub struct ScenePlayback {
    cam: EventCamera,
    start_ns: i64,
    end_ns: i64,
    batch_ns: i64,
    seq: u64,
    events: usize,
}

impl ScenePlayback {
    /// The next batch, or `None` at `end_ns`.
    pub fn next_step(&mut self) -> Option<EventStep> {
        if self.cam.time_ns() >= self.end_ns {
            return None;
        }
        let t_end = self
            .cam
            .time_ns()
            .saturating_add(self.batch_ns)
            .min(self.end_ns);
        let batch: EventBatch = self.cam.advance_to(t_end, self.seq);
        self.events += batch.len();
        self.seq += 1;
        Some(EventStep {
            batch,
            due_ns: t_end.saturating_sub(self.start_ns),
        })
    }
}
/// An event recording cut into batches of consecutive `batch_ns` intervals.
pub struct EventFile {
    reader: Box<dyn EventReader + Send>,
    path: PathBuf,
    resolution: Resolution,
    /// Decoded events not yet batched: `pending[pos..]`.
    pending: EventBatch,
    pos: usize,
    /// The reader is exhausted (`eof`) or failed (`error`, reported after the good events).
    eof: bool,
    error: Option<FormatError>,
    /// The requested interval and the batch length.
    start_ns: Option<i64>,
    end_ns: Option<i64>,
    batch_ns: i64,
    /// Start of the stream (first batch), once known, and of the next batch.
    stream_start_ns: Option<i64>,
    next_start_ns: Option<i64>,
    /// Batches made so far (the next batch's `seq`).
    seq: u64,
    /// Last event batched.
    last_t_ns: Option<i64>,
    /// Events batched so far.
    events: usize,
    /// Events before `start_ns`, read and dropped.
    skipped_before_start: u64,
    done: bool,
}

impl EventFile {
    /// Opens any event recording; `resolution` is needed when the file does not state its size.
    pub fn open(
        path: &Path,
        resolution: Option<Resolution>,
        start_ns: Option<i64>,
        end_ns: Option<i64>,
        batch_ns: i64,
    ) -> Result<Self, FormatError> {
        let format = sniff(path)?;
        let opts = ReadOptions {
            resolution,
            ..ReadOptions::default()
        };
        let reader = open_events(path, &opts)?;
        let resolution = reader.resolution();
        tracing::info!(
            file = %path.display(),
            %format,
            %resolution,
            "opened an event recording"
        );
        Ok(EventFile {
            pending: EventBatch::empty(resolution.width.into(), resolution.height.into(), 0, 0, 0),
            reader,
            path: path.to_path_buf(),
            resolution,
            pos: 0,
            eof: false,
            error: None,
            start_ns,
            end_ns,
            batch_ns: batch_ns.max(1),
            stream_start_ns: None,
            next_start_ns: None,
            seq: 0,
            last_t_ns: None,
            events: 0,
            skipped_before_start: 0,
            done: false,
        })
    }

    /// Makes sure `pending[pos..]` holds an event; false when the recording has no more (at its
    /// end, or after a fault).
    fn fill(&mut self) -> bool {
        while self.pos == self.pending.len() {
            if self.eof || self.error.is_some() {
                return false;
            }
            let p = &mut self.pending;
            p.t_ns.clear();
            p.x.clear();
            p.y.clear();
            p.polarity.clear();
            self.pos = 0;
            match self.reader.read_into(&mut self.pending, READ_EVENTS) {
                Ok(0) => self.eof = true,
                Ok(_) => {}
                Err(e) => self.error = Some(e),
            }
        }
        true
    }

    /// Time of the next unbatched event.
    fn peek_t_ns(&mut self) -> Option<i64> {
        if self.fill() {
            Some(self.pending.t_ns[self.pos])
        } else {
            None
        }
    }

    /// Ends the stream: `None`, or the fault that ended it.
    fn finish(&mut self) -> Result<Option<EventBatch>, FormatError> {
        self.done = true;
        match self.error.take() {
            Some(e) => Err(e),
            None => Ok(None),
        }
    }

    /// The start of the first batch: `--start-ns`, or the first event's time; earlier events
    /// are dropped.
    fn first_start(&mut self) -> Option<i64> {
        let start = match self.start_ns {
            Some(s) => s,
            None => self.peek_t_ns()?,
        };
        while self.fill() {
            let ts = &self.pending.t_ns[self.pos..];
            let k = ts.partition_point(|&t| t < start);
            self.skipped_before_start += k as u64;
            self.pos += k;
            if k < ts.len() {
                break;
            }
        }
        self.stream_start_ns = Some(start);
        Some(start)
    }

    /// The next batch, covering `[previous t_end_ns, + batch_ns)`, or `None` at the end of the
    /// stream. A fault in the recording is returned after every batch before it.
    pub fn next_batch(&mut self) -> Result<Option<EventBatch>, FormatError> {
        if self.done {
            return self.finish();
        }
        let t0 = match self.next_start_ns {
            Some(t) => t,
            None => match self.first_start() {
                Some(t) => t,
                None => {
                    tracing::warn!(file = %self.path.display(), "the recording has no event to play");
                    return self.finish();
                }
            },
        };
        let mut t1 = t0.saturating_add(self.batch_ns);
        if let Some(end) = self.end_ns {
            t1 = t1.min(end);
        }
        if t1 <= t0 {
            // At --end-ns, or at the end of the clock.
            return self.finish();
        }
        let (w, h) = (self.resolution.width.into(), self.resolution.height.into());
        let mut batch = EventBatch::empty(w, h, t0, t1, self.seq);
        let mut exhausted = true;
        while self.fill() {
            let (p, from) = (&self.pending, self.pos);
            let k = p.t_ns[from..].partition_point(|&t| t < t1);
            batch.t_ns.extend_from_slice(&p.t_ns[from..from + k]);
            batch.x.extend_from_slice(&p.x[from..from + k]);
            batch.y.extend_from_slice(&p.y[from..from + k]);
            batch
                .polarity
                .extend_from_slice(&p.polarity[from..from + k]);
            self.pos += k;
            if self.pos < self.pending.len() {
                exhausted = false;
                break;
            }
        }
        if let Some(&t) = batch.t_ns.last() {
            self.last_t_ns = Some(t);
        }
        // A gap in the recording: one empty batch up to the interval of the next event, not one
        // per `batch_ns` across it (a day's gap would be 86 million of them at 1 ms).
        if batch.is_empty()
            && !exhausted
            && let Some(gap) = self
                .pending
                .t_ns
                .get(self.pos)
                .and_then(|&t| t.checked_sub(t0))
        {
            let whole = gap / self.batch_ns * self.batch_ns;
            let mut far = t0.saturating_add(whole);
            if let Some(end) = self.end_ns {
                far = far.min(end);
            }
            batch.t_end_ns = far.max(t1);
        }
        if exhausted {
            // The recording ends inside this interval: the stream ends after its last event.
            match self.last_t_ns {
                Some(last) if last >= t0 => batch.t_end_ns = t1.min(last.saturating_add(1)),
                _ => return self.finish(),
            }
            self.done = true;
        }
        self.next_start_ns = Some(batch.t_end_ns);
        self.seq += 1;
        self.events += batch.len();
        Ok(Some(batch))
    }
}

/// The event camera as a source stage: output `events`, one batch per interval, each sent when
/// its pace says ([`Pacer`]), stamped with the wall time its camera would have delivered it.
pub struct EventSourceStage {
    source: EventSource,
    pacer: Pacer,
}

impl EventSourceStage {
    /// The stage of `source`, paced by `pacer`.
    pub fn new(source: EventSource, pacer: Pacer) -> Self {
        EventSourceStage { source, pacer }
    }
}

impl Stage for EventSourceStage {
    fn name(&self) -> &str {
        "event-source"
    }

    fn inputs(&self) -> Vec<Port> {
        vec![]
    }

    fn outputs(&self) -> Vec<Port> {
        vec![Port::new("events", MsgType::EventBatch)]
    }

    fn step(&mut self, out: &mut Outbox) -> eyre::Result<Flow> {
        let Some(step) = self.source.next_step()? else {
            return Ok(Flow::Stop);
        };
        if let Some(due_unix_ns) = self.pacer.wait_until(step.due_ns) {
            out.set_origin(due_unix_ns);
        }
        out.send("events", step.batch);
        Ok(Flow::Continue)
    }

    fn on_message(&mut self, _: &str, _: Msg, _: &mut Outbox) -> eyre::Result<Flow> {
        Ok(Flow::Continue)
    }

    fn finish(&mut self, _: &Tallies, _: &mut Outbox) -> eyre::Result<()> {
        self.source.log_end();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> EventSourceConfig {
        EventSourceConfig {
            scene: "bright-slow".into(),
            file: None,
            file_width: None,
            file_height: None,
            start_ns: None,
            batch_ns: 1_000_000,
            end_ns: Some(3_500_000),
            camera: DvsConfig {
                width: 32,
                height: 24,
                ..DvsConfig::default()
            },
        }
    }

    #[test]
    fn a_scene_is_cut_into_consecutive_batches_up_to_its_end() {
        let mut source = EventSource::open(&config()).expect("scene");
        let steps: Vec<EventStep> =
            std::iter::from_fn(|| source.next_step().expect("step")).collect();
        let spans: Vec<(u64, i64, i64, i64)> = steps
            .iter()
            .map(|s| (s.batch.seq, s.batch.t_start_ns, s.batch.t_end_ns, s.due_ns))
            .collect();
        assert_eq!(
            spans,
            [
                (0, 0, 1_000_000, 1_000_000),
                (1, 1_000_000, 2_000_000, 2_000_000),
                (2, 2_000_000, 3_000_000, 3_000_000),
                (3, 3_000_000, 3_500_000, 3_500_000)
            ]
        );
        for s in &steps {
            let b = &s.batch;
            assert!(
                b.t_ns
                    .iter()
                    .all(|&t| (b.t_start_ns..b.t_end_ns).contains(&t))
            );
        }
    }

    #[test]
    fn an_interval_that_ends_before_it_starts_is_refused_by_name() {
        let cfg = EventSourceConfig {
            file: Some(PathBuf::from("events.txt")),
            start_ns: Some(5),
            end_ns: Some(5),
            ..config()
        };
        let e = EventSource::open(&cfg).err().expect("refused").to_string();
        assert!(e.contains("end-ns") && e.contains("start-ns"), "{e}");
    }
}
