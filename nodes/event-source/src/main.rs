//! dora node: the DVS event camera, simulated or played from a recording. Output `events`
//! (EventBatch), one batch per `--batch-ns` interval, empty batches included, so a receiver always
//! knows how far time went.
//!
//! With `--file PATH` the node plays any event recording `neuspike_formats::open_events` reads
//! (Event Camera Dataset text, Prophesee RAW EVT 2.0 / 3.0, Prophesee DAT; told apart by content)
//! instead of simulating a scene. `--file-width`/`--file-height` give the sensor size of files
//! that do not state it (and must agree with files that do). Batches cover consecutive half-open
//! intervals `[t_start_ns, t_end_ns)` of `--batch-ns`, exactly as the simulator's do, from
//! `--start-ns` (default: the first event's time) to `--end-ns` or the end of the recording
//! (the last event's time + 1 ns), whichever comes first; the last batch is shortened to it. Event
//! times are the recording's own; align's `--event-offset-ns` moves them onto the spike clock.
//! The file is decoded a buffer at a time: memory is bounded by the read buffer and one batch.
//!
//! A recording that turns out bad part-way (corrupt word, step back in time) has every batch
//! before the fault sent, the last one ending just after the last good event; then the error,
//! naming the file and the byte offset or line, is logged, the end-of-stream marker is sent and
//! the node fails. A relative `--file` is resolved against the node's working directory: under
//! `neuspike run` (dora), the graph's folder.
//!
//! `--pace realtime` sends each batch when the camera would have finished it (wall clock from the
//! node's start, camera clock from the stream's start); `--pace fast` (default) sends as fast as
//! the receivers take them.

use std::path::{Path, PathBuf};

use dora_node_api::{DoraNode, EventStream};
use eyre::WrapErr;
use neuspike_event_source::{DvsConfig, EventCamera};
use neuspike_formats::{EventReader, FormatError, ReadOptions, Resolution, open_events, sniff};
use neuspike_scene::Scene;
use neuspike_schemas::EventBatch;
use neuspike_schemas::node::{self, Pace, Pacer, output, send, send_end, stop_requested};

/// Events decoded per read from a recording (the read buffer's size).
const READ_EVENTS: usize = 1 << 16;

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-event-source",
    about = "DVS event camera: simulated, or played from a recording",
    args_override_self = true
)]
struct Args {
    /// Built-in scene name or path of a scene YAML file.
    #[arg(long, default_value = "bright-slow", conflicts_with = "file")]
    scene: String,
    /// Play this event recording (ECD text, Prophesee RAW EVT 2.0/3.0 or DAT) instead of
    /// simulating a scene (its size comes from the file or `--file-width`/`--file-height`, not
    /// the simulator's `--width`/`--height`).
    #[arg(long, conflicts_with_all = ["width", "height"])]
    file: Option<PathBuf>,
    /// Sensor width of a recording whose header does not state it.
    #[arg(long, requires_all = ["file", "file_height"],
          value_parser = clap::value_parser!(u16).range(1..))]
    file_width: Option<u16>,
    /// Sensor height of a recording whose header does not state it.
    #[arg(long, requires_all = ["file", "file_width"],
          value_parser = clap::value_parser!(u16).range(1..))]
    file_height: Option<u16>,
    /// Start of the first batch, nanoseconds on the recording's clock (default: the first
    /// event's time); earlier events are skipped.
    #[arg(long, requires = "file", allow_negative_numbers = true)]
    start_ns: Option<i64>,
    /// Length of the interval each batch covers, nanoseconds.
    #[arg(long, default_value_t = 1_000_000, value_parser = clap::value_parser!(i64).range(1..))]
    batch_ns: i64,
    /// Stop at this time, nanoseconds (default: the scene's duration, or the end of the
    /// recording).
    #[arg(long, allow_negative_numbers = true)]
    end_ns: Option<i64>,
    /// `fast`: send as fast as possible; `realtime`: send each batch when its interval has passed.
    #[arg(long, value_enum, default_value_t = Pace::Fast)]
    pace: Pace,
    #[command(flatten)]
    camera: DvsConfig,
}

/// Where the events come from.
enum Source {
    /// The simulated camera looking at a scene.
    Scene(Box<EventCamera>),
    /// A recording.
    File(Box<EventFile>),
}

/// Checks the arguments and opens the scene or the file, before any message is sent.
fn open_source(args: &Args) -> eyre::Result<Source> {
    match &args.file {
        None => {
            let scene = Scene::load(&args.scene).wrap_err("event-source: cannot load the scene")?;
            Ok(Source::Scene(Box::new(EventCamera::new(
                scene,
                args.camera.clone(),
                0,
            )?)))
        }
        Some(path) => {
            if let (Some(start), Some(end)) = (args.start_ns, args.end_ns)
                && end <= start
            {
                eyre::bail!(
                    "event-source: `end-ns` = {end} is invalid: must be after `start-ns` = {start}"
                );
            }
            let resolution = match (args.file_width, args.file_height) {
                (Some(w), Some(h)) => Some(Resolution::new(w, h)),
                _ => None,
            };
            let file = EventFile::open(path, resolution, args.start_ns, args.end_ns, args.batch_ns)
                .wrap_err(
                    "event-source: cannot play the recording (--file-width and --file-height \
                     give the sensor size of files that do not state it)",
                )?;
            Ok(Source::File(Box::new(file)))
        }
    }
}

/// An event recording cut into batches of consecutive `batch_ns` intervals.
struct EventFile {
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
    /// Events before `start_ns`, read and dropped.
    skipped_before_start: u64,
    done: bool,
}

impl EventFile {
    /// Opens any event recording; `resolution` is needed when the file does not state its size.
    fn open(
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
    fn next_batch(&mut self) -> Result<Option<EventBatch>, FormatError> {
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
        Ok(Some(batch))
    }
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("event-source")?;
    let source = open_source(&args)?;
    let (node, events) = DoraNode::init_from_env()?;
    node::run_on_rayon("event-source", || run(node, events, source, &args))
}

fn run(node: DoraNode, events: EventStream, source: Source, args: &Args) -> eyre::Result<()> {
    match source {
        Source::Scene(cam) => simulate(node, events, *cam, args),
        Source::File(file) => play(node, events, *file, args),
    }
}

/// Streams the recording: every batch decoded, then the end marker, whatever happened.
fn play(
    mut node: DoraNode,
    mut events: EventStream,
    mut file: EventFile,
    args: &Args,
) -> eyre::Result<()> {
    let out = output("events");
    tracing::info!(
        file = %file.path.display(),
        start_ns = ?args.start_ns,
        end_ns = ?args.end_ns,
        batch_ns = args.batch_ns,
        pace = ?args.pace,
        "playing an event recording"
    );
    let pacer = Pacer::start(args.pace);
    let mut total = 0usize;
    let mut failure = None;
    loop {
        if stop_requested(&mut events) {
            break;
        }
        match file.next_batch() {
            Ok(Some(batch)) => {
                let start = file.stream_start_ns.unwrap_or(batch.t_start_ns);
                pacer.wait_until(batch.t_end_ns.saturating_sub(start));
                total += batch.len();
                send(&mut node, &out, &batch)?;
            }
            Ok(None) => break,
            Err(e) => {
                tracing::error!("{e}; the stream ends after the events read before it");
                failure = Some(e);
                break;
            }
        }
    }
    send_end::<EventBatch>(&mut node, &out, file.seq)?;
    let stats = file.reader.stats();
    tracing::info!(
        batches = file.seq,
        events = total,
        first_ns = ?file.stream_start_ns,
        end_ns = ?file.next_start_ns,
        skipped_before_start = file.skipped_before_start,
        duplicates = stats.duplicate_events,
        time_wraps = stats.time_wraps,
        without_time_base = stats.events_without_time_base,
        "event recording played"
    );
    match failure {
        Some(e) => Err(e).wrap_err("event-source: the recording could not be read to its end"),
        None => Ok(()),
    }
}

fn simulate(
    mut node: DoraNode,
    mut events: EventStream,
    mut cam: EventCamera,
    args: &Args,
) -> eyre::Result<()> {
    let out = output("events");
    let end_ns = args.end_ns.unwrap_or_else(|| cam.scene().duration_ns());
    tracing::info!(end_ns, step_ns = cam.step_ns(), pace = ?args.pace, "event camera started");
    let pacer = Pacer::start(args.pace);
    let start = cam.time_ns();
    let mut seq = 0u64;
    let mut total = 0usize;
    while cam.time_ns() < end_ns {
        if stop_requested(&mut events) {
            break;
        }
        let t_end = cam.time_ns().saturating_add(args.batch_ns).min(end_ns);
        let batch: EventBatch = cam.advance_to(t_end, seq);
        total += batch.len();
        pacer.wait_until(t_end.saturating_sub(start));
        send(&mut node, &out, &batch)?;
        seq += 1;
    }
    send_end::<EventBatch>(&mut node, &out, seq)?;
    tracing::info!(batches = seq, events = total, "event camera finished");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use dora_node_api::integration_testing::OutputJson;
    use neuspike_formats::Event as Ev;
    use neuspike_formats::raw::Evt2Writer;
    use neuspike_formats::text::TextWriter;
    use neuspike_schemas::testing::{CannedInputs, output_ids, payload_len};
    use std::time::{Duration, Instant};

    fn args(extra: &[&str]) -> Args {
        Args::try_parse_from(std::iter::once("event-source").chain(extra.iter().copied())).unwrap()
    }

    fn play_args(args: &Args) -> Vec<OutputJson> {
        let source = open_source(args).unwrap();
        let dir = tempfile::tempdir().unwrap();
        CannedInputs::new(dir.path())
            .run(|node, events| run(node, events, source, args))
            .unwrap()
    }

    /// The events of an output, from dora's testing JSON.
    fn payload_events(o: &OutputJson) -> Vec<Ev> {
        o["data"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| Ev {
                t_ns: e["t_ns"].as_i64().unwrap(),
                x: u16::try_from(e["x"].as_u64().unwrap()).unwrap(),
                y: u16::try_from(e["y"].as_u64().unwrap()).unwrap(),
                polarity: i8::try_from(e["polarity"].as_i64().unwrap()).unwrap(),
            })
            .collect()
    }

    /// Every batch `EventFile` makes for `args` (the headers `run` sends).
    fn batches(args: &Args) -> Vec<EventBatch> {
        let Source::File(mut f) = open_source(args).unwrap() else {
            panic!("a file source")
        };
        let mut out = Vec::new();
        while let Some(b) = f.next_batch().unwrap() {
            out.push(b);
        }
        out
    }

    /// Asserts consecutive half-open intervals numbered from 0, events inside their interval.
    fn assert_contiguous(bs: &[EventBatch]) {
        for (i, b) in bs.iter().enumerate() {
            assert_eq!(b.seq, i as u64);
            assert!(b.t_start_ns < b.t_end_ns, "batch {i}");
            if i > 0 {
                assert_eq!(
                    b.t_start_ns,
                    bs[i - 1].t_end_ns,
                    "batch {i} starts where {i}-1 ended"
                );
            }
            assert!(
                b.t_ns.iter().all(|&t| b.t_start_ns <= t && t < b.t_end_ns),
                "batch {i}"
            );
        }
    }

    fn ev(t_ns: i64, x: u16, y: u16, polarity: i8) -> Ev {
        Ev {
            t_ns,
            x,
            y,
            polarity,
        }
    }

    /// Ten events from 1.000 ms to 5.5 ms, two at the same time, one gap of 2 ms.
    fn sample() -> Vec<Ev> {
        vec![
            ev(1_000_000, 0, 0, 1),
            ev(1_200_000, 3, 1, -1),
            ev(1_200_000, 4, 2, 1),
            ev(1_999_999, 5, 2, -1),
            ev(2_000_000, 6, 0, 1),
            ev(2_500_000, 7, 1, 1),
            ev(4_600_000, 1, 2, -1),
            ev(5_000_000, 2, 0, 1),
            ev(5_000_001, 2, 1, -1),
            ev(5_500_000, 9, 2, 1),
        ]
    }

    fn write_text(dir: &Path, events: &[Ev], size_line: bool) -> PathBuf {
        let path = dir.join("events.txt");
        let mut w = TextWriter::new(Vec::new(), &path, Resolution::new(10, 3), size_line).unwrap();
        for e in events {
            w.write_event(e).unwrap();
        }
        std::fs::write(&path, w.finish().unwrap().0).unwrap();
        path
    }

    #[test]
    fn batches_cover_time_and_end() {
        let args = args(&[
            "--scene",
            "bright-fast",
            "--width",
            "34",
            "--height",
            "26",
            "--batch-ns",
            "1000000",
            "--end-ns",
            "3500000",
        ]);
        let out = play_args(&args);
        // 3.5 ms in 1 ms batches: 4 batches and the marker.
        assert_eq!(output_ids(&out), vec!["events"; 5]);
        assert!(
            out[..4].iter().map(payload_len).sum::<usize>() > 0,
            "a fast scene makes events"
        );
        assert_eq!(payload_len(&out[4]), 0);
    }

    #[test]
    fn file_arguments_are_checked() {
        let bad = |a: &[&str]| {
            Args::try_parse_from(std::iter::once("event-source").chain(a.iter().copied()))
                .unwrap_err()
                .to_string()
        };
        let e = bad(&["--file", "e.txt", "--scene", "bright-fast"]);
        assert!(e.contains("--scene") && e.contains("--file"), "{e}");
        let e = bad(&["--file", "e.txt", "--file-width", "240"]);
        assert!(e.contains("--file-height"), "{e}");
        let e = bad(&["--file", "e.txt", "--height", "180"]);
        assert!(e.contains("--height") && e.contains("--file"), "{e}");
        let e = bad(&["--start-ns", "5"]);
        assert!(e.contains("--file"), "{e}");
        let e = bad(&["--file", "e.txt", "--pace", "slow"]);
        assert!(e.contains("pace") && e.contains("slow"), "{e}");
        let a = args(&["--file", "e.txt", "--start-ns", "-5", "--end-ns", "-1"]);
        assert_eq!((a.start_ns, a.end_ns), (Some(-5), Some(-1)));
        let e = format!(
            "{:#}",
            open_source(&args(&[
                "--file",
                "e.txt",
                "--start-ns",
                "5",
                "--end-ns",
                "5"
            ]))
            .err()
            .unwrap()
        );
        assert!(e.contains("end-ns") && e.contains("start-ns"), "{e}");
    }

    #[test]
    fn bad_files_are_named_before_any_message() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_text(dir.path(), &sample(), false);
        let p = path.to_str().unwrap();
        // No size line and no --file-width/--file-height.
        let e = format!("{:#}", open_source(&args(&["--file", p])).err().unwrap());
        assert!(e.contains("events.txt"), "{e}");
        // A size that disagrees with the file's.
        let path = write_text(dir.path(), &sample(), true);
        let p = path.to_str().unwrap();
        let e = format!(
            "{:#}",
            open_source(&args(&[
                "--file",
                p,
                "--file-width",
                "11",
                "--file-height",
                "3"
            ]))
            .err()
            .unwrap()
        );
        assert!(e.contains("events.txt"), "{e}");
    }

    #[test]
    fn plays_a_written_text_file_in_contiguous_batches() {
        let dir = tempfile::tempdir().unwrap();
        let events = sample();
        let path = write_text(dir.path(), &events, false);
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-width",
            "10",
            "--file-height",
            "3",
        ]);
        let out = play_args(&a);
        // From the first event (1 ms) to the last + 1 ns (5.5 ms + 1 ns): five batches, the
        // fourth empty, the last shortened.
        assert_eq!(output_ids(&out), vec!["events"; 6]);
        let sent: Vec<Vec<Ev>> = out.iter().map(payload_events).collect();
        assert_eq!(
            sent.iter().map(Vec::len).collect::<Vec<_>>(),
            [4, 2, 0, 1, 3, 0]
        );
        assert_eq!(sent.concat(), events);

        let bs = batches(&a);
        assert_contiguous(&bs);
        let intervals: Vec<(i64, i64)> = bs.iter().map(|b| (b.t_start_ns, b.t_end_ns)).collect();
        assert_eq!(
            intervals,
            [
                (1_000_000, 2_000_000),
                (2_000_000, 3_000_000),
                (3_000_000, 4_000_000),
                (4_000_000, 5_000_000),
                (5_000_000, 5_500_001)
            ]
        );
        assert!(bs.iter().all(|b| (b.width, b.height) == (10, 3)));
    }

    #[test]
    fn start_end_and_batch_length_cut_an_evt2_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("events.raw");
        let mut w = Evt2Writer::new(Vec::new(), &path, Resolution::new(10, 3)).unwrap();
        for e in sample() {
            w.write_event(&e).unwrap();
        }
        std::fs::write(&path, w.finish().unwrap().0).unwrap();
        let p = path.to_str().unwrap();

        let a = args(&[
            "--file",
            p,
            "--start-ns",
            "1500000",
            "--end-ns",
            "5000001",
            "--batch-ns",
            "1500000",
        ]);
        let bs = batches(&a);
        assert_contiguous(&bs);
        let intervals: Vec<(i64, i64)> = bs.iter().map(|b| (b.t_start_ns, b.t_end_ns)).collect();
        assert_eq!(
            intervals,
            [
                (1_500_000, 3_000_000),
                (3_000_000, 4_500_000),
                (4_500_000, 5_000_001)
            ]
        );
        let counts: Vec<usize> = bs.iter().map(EventBatch::len).collect();
        // EVT 2.0 keeps microseconds: 1,999,999 ns comes back as 1,999,000.
        assert_eq!(counts, [3, 0, 3]);
        assert_eq!(bs[0].t_ns, [1_999_000, 2_000_000, 2_500_000]);
        assert_eq!(bs[2].t_ns, [4_600_000, 5_000_000, 5_000_000]);

        let out = play_args(&a);
        assert_eq!(
            out.iter().map(payload_len).collect::<Vec<_>>(),
            [3, 0, 3, 0],
            "three batches and the marker"
        );

        // A window after the last event: nothing to play, just the marker.
        let a = args(&["--file", p, "--start-ns", "9000000"]);
        assert!(batches(&a).is_empty());
        assert_eq!(play_args(&a).len(), 1);
    }

    #[test]
    fn a_corrupt_file_delivers_what_came_before_the_fault() {
        let dir = tempfile::tempdir().unwrap();
        let events = sample();
        let path = write_text(dir.path(), &events, true);
        let mut text = std::fs::read_to_string(&path).unwrap();
        text.push_str("6.000000000 99 1 1\n7.000000000 1 1 1\n");
        std::fs::write(&path, text).unwrap();
        let a = args(&["--file", path.to_str().unwrap()]);
        let Source::File(mut f) = open_source(&a).unwrap() else {
            panic!("a file source")
        };
        let mut good = Vec::new();
        let e = loop {
            match f.next_batch() {
                Ok(Some(b)) => good.push(b),
                Ok(None) => panic!("the fault must be reported"),
                Err(e) => break e,
            }
        };
        assert_contiguous(&good);
        assert_eq!(
            good.iter().map(EventBatch::len).sum::<usize>(),
            events.len()
        );
        assert_eq!(good.last().unwrap().t_end_ns, 5_500_001);
        let msg = e.to_string();
        assert!(
            msg.contains("events.txt") && msg.contains("line 12"),
            "{msg}"
        );
        assert!(f.next_batch().unwrap().is_none());

        // Through the node: the batches, the marker, then the node fails naming the fault.
        let source = open_source(&a).unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let e = CannedInputs::new(tmp.path())
            .run(|node, events| run(node, events, source, &a))
            .unwrap_err();
        assert!(format!("{e:#}").contains("line 12"), "{e:#}");
    }

    #[test]
    fn realtime_pace_follows_the_recording_clock() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_text(dir.path(), &sample(), true);
        let a = args(&["--file", path.to_str().unwrap(), "--pace", "realtime"]);
        let start = Instant::now();
        let out = play_args(&a);
        // The stream covers 4.5 ms of the recording.
        assert!(start.elapsed() >= Duration::from_micros(4_500));
        assert_eq!(out.len(), 6);
    }

    #[test]
    fn plays_the_real_davis_text() {
        let Some(path) =
            neuspike_schemas::testing::real_recording("davis240c-shapes-rotation-events.txt")
        else {
            return;
        };
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-width",
            "240",
            "--file-height",
            "180",
        ]);
        let out = play_args(&a);
        // 2.097134001 s to 2.195729 s in 1 ms batches: 99 batches and the marker.
        assert_eq!(out.len(), 100);
        let sent: Vec<Vec<Ev>> = out.iter().map(payload_events).collect();
        let all = sent.concat();
        assert_eq!(all.len(), 20_000);
        assert_eq!(all[0], ev(2_097_134_001, 162, 27, -1));
        assert_eq!(all[19_999], ev(2_195_729_000, 127, 147, 1));
        let bs = batches(&a);
        assert_contiguous(&bs);
        assert_eq!(bs[0].t_start_ns, 2_097_134_001);
        assert_eq!(bs[98].t_end_ns, 2_195_729_001);
    }

    #[test]
    fn plays_the_real_prophesee_raw() {
        let Some(path) = neuspike_schemas::testing::real_recording("prophesee-evt2-640x480.raw")
        else {
            return;
        };
        // Its header states no geometry: the README gives 640x480.
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-width",
            "640",
            "--file-height",
            "480",
            "--batch-ns",
            "10000000",
        ]);
        let bs = batches(&a);
        assert_contiguous(&bs);
        assert_eq!(bs.iter().map(EventBatch::len).sum::<usize>(), 521_252);
        assert_eq!(bs[0].t_start_ns, 913_716_224_000);
        assert_eq!(bs.last().unwrap().t_end_ns, 913_812_095_001);
        assert_eq!(bs.len(), 10);
        assert!(bs.iter().all(|b| (b.width, b.height) == (640, 480)));
        let out = play_args(&a);
        assert_eq!(out.len(), 11);
        assert_eq!(out.iter().map(payload_len).sum::<usize>(), 521_252);
    }
}
