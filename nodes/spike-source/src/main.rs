//! dora node: the spike camera, simulated or played from a recording. Output `spikes`
//! (SpikeChunk) and, when simulating and asked, `ground_truth` (Frame) at every
//! `--gt-every-planes`-th plane.
//!
//! With `--file PATH` the node plays a PKU Vidar `.dat` recording instead of simulating a scene
//! (`--scene` and `--gt-every-planes` are then refused; `--truth` names the recording's ground
//! truth, a folder of PNGs or the APS frames of an AEDAT 4 file, see [`Truth`]). The file
//! is streamed `--chunk-planes` planes at a time, never loaded whole, and its planes go out as the
//! simulator's do: chunks numbered by `seq` from 0, planes numbered by their place in the file
//! (the first one sent is `--start-plane`), plane `k` stamped `k * T` with `T = 1 / --rate-hz`
//! (default 20 kHz, the Vidar rate), then the end-of-stream marker. Played from its middle, a
//! recording keeps its clock, so that an event file and ground truth recorded with it (both
//! counted from the recording's start) still line up. A file that ends in a partial plane
//! (truncated, or the wrong
//! `--file-width`/`--file-height`/`--head-columns`) has its whole planes sent, then an error naming
//! the file and the byte offset of the partial plane is logged and the stream still ends with its
//! marker. A relative `--file` is resolved against the node's working directory: under
//! `neuspike run` (dora), the graph's folder.
//!
//! The chunks of a recording carry `lum_per_rate` = `--lum-per-rate`, default
//! [`DEFAULT_FILE_LUM_PER_RATE`] (1.0): a recording states no calibration, and with 1.0 a TFP
//! frame is the firing rate itself (a pixel firing at every plane is white), the usual way Vidar
//! TFP images are shown. The infer node's own `--lum-per-rate` overrides it.
//!
//! `--pace realtime` sends each chunk when its last plane would have been read out by the camera
//! (plane rate `--rate-hz`, wall clock from the node's start); `--pace fast` (default) sends as
//! fast as the receivers take them.

use std::fs::File;
use std::io::{Seek, SeekFrom};
use std::path::{Path, PathBuf};

use dora_node_api::{DoraNode, EventStream};
use eyre::WrapErr;
use neuspike_formats::FormatError;
use neuspike_formats::pku::{HEAD_COLUMNS, PkuGeometry, PkuOptions, PkuReader};
use neuspike_scene::Scene;
use neuspike_schemas::node::{self, Pace, Pacer, output, send, send_end, stop_requested};
use neuspike_schemas::{Frame, FrameKind, SpikeChunk};
use neuspike_spike_source::truth::Truth;
use neuspike_spike_source::{CameraConfig, SpikeCamera};

/// Luminance per unit firing rate sent with the planes of a recording when the graph gives no
/// `--lum-per-rate`: TFP frames show the firing rate (0.366 on average in the Vidar car sample).
const DEFAULT_FILE_LUM_PER_RATE: f64 = 1.0;

/// Node arguments (the graph's `args:`).
#[derive(Debug, clap::Parser)]
#[command(
    name = "neuspike-spike-source",
    about = "Spike camera: simulated, or played from a PKU .dat recording",
    args_override_self = true
)]
struct Args {
    /// Built-in scene name or path of a scene YAML file.
    #[arg(long, default_value = "bright-slow", conflicts_with = "file")]
    scene: String,
    /// Play this PKU spike `.dat` recording instead of simulating a scene (its size is
    /// `--file-width`/`--file-height`, not the simulator's `--width`/`--height`).
    #[arg(long, conflicts_with_all = ["width", "height"])]
    file: Option<PathBuf>,
    /// Width of the recording's planes in pixels (head columns not included).
    #[arg(long, default_value_t = 400, requires = "file",
          value_parser = clap::value_parser!(u16).range(1..))]
    file_width: u16,
    /// Height of the recording's planes in pixels.
    #[arg(long, default_value_t = 250, requires = "file",
          value_parser = clap::value_parser!(u16).range(1..))]
    file_height: u16,
    /// Extra columns stored at the end of each row of the recording and dropped: 0 or 16.
    #[arg(long, default_value_t = 0, requires = "file", value_parser = parse_head_columns)]
    head_columns: usize,
    /// First plane of the recording to play (the planes before it are skipped by seeking).
    #[arg(long, default_value_t = 0, requires = "file")]
    start_plane: u64,
    /// Ground truth recorded with the file: a folder whose `timestamps.txt` lists `plane t_ns
    /// file` (as `neuspike simulate` writes `ground-truth/`), each listed plane that is played
    /// sending its PNG on `ground_truth` at that plane's time; or an AEDAT 4 file whose APS
    /// frames are sent at their own times (on the spike clock) as the planes around them play.
    #[arg(long, requires = "file")]
    truth: Option<PathBuf>,
    /// Luminance per unit firing rate sent with the recording's planes (default 1.0).
    #[arg(long, requires = "file")]
    lum_per_rate: Option<f64>,
    /// Planes per output message.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    chunk_planes: u32,
    /// Emit the ground-truth frame at every plane whose index is a multiple of this (0 = never).
    #[arg(long, default_value_t = 0, conflicts_with = "file")]
    gt_every_planes: u64,
    /// Stop after this many planes (default: the scene's duration, or the whole recording).
    #[arg(long)]
    max_planes: Option<u64>,
    /// `fast`: send as fast as possible; `realtime`: send at the plane rate `--rate-hz`.
    #[arg(long, value_enum, default_value_t = Pace::Fast)]
    pace: Pace,
    #[command(flatten)]
    camera: CameraConfig,
}

fn parse_head_columns(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Ok(0),
        Ok(n) if n == HEAD_COLUMNS => Ok(n),
        _ => Err(format!("`{s}` is not 0 or {HEAD_COLUMNS}")),
    }
}

/// Where the planes come from.
enum Source {
    /// The simulated camera looking at a scene.
    Scene(Box<SpikeCamera>),
    /// A recording.
    File(Box<SpikeFile>),
}

/// Checks the arguments and opens the scene or the file, before any message is sent.
fn open_source(args: &Args) -> eyre::Result<Source> {
    let period_ns = args.camera.validate()?;
    match &args.file {
        None => {
            let scene = Scene::load(&args.scene).wrap_err("spike-source: cannot load the scene")?;
            Ok(Source::Scene(Box::new(SpikeCamera::new(
                scene,
                args.camera.clone(),
            )?)))
        }
        Some(path) => {
            let lum_per_rate = args.lum_per_rate.unwrap_or(DEFAULT_FILE_LUM_PER_RATE);
            if !(lum_per_rate.is_finite() && lum_per_rate > 0.0) {
                eyre::bail!(
                    "spike-source: `lum-per-rate` = {lum_per_rate} is invalid: must be finite and > 0"
                );
            }
            let geometry = PkuGeometry {
                width: args.file_width.into(),
                height: args.file_height.into(),
                head_columns: args.head_columns,
            };
            let mut file =
                SpikeFile::open(path, geometry, args.start_plane, period_ns, lum_per_rate)
                    .wrap_err("spike-source: cannot play the recording")?;
            if let Some(dir) = &args.truth {
                file.truth = Some(Truth::open(dir).map_err(|e| eyre::eyre!("spike-source: {e}"))?);
            }
            Ok(Source::File(Box::new(file)))
        }
    }
}

/// A PKU `.dat` recording being played from `--start-plane` on, a chunk at a time.
struct SpikeFile {
    reader: PkuReader<File>,
    path: PathBuf,
    geometry: PkuGeometry,
    /// Planes skipped at the start, and the bytes they take.
    start_plane: u64,
    skip_bytes: u64,
    /// Whole planes in the file, and bytes after the last one.
    planes_in_file: u64,
    tail_bytes: u64,
    plane_period_ns: i64,
    lum_per_rate: f64,
    /// Ground truth recorded with the file (`--truth`).
    truth: Option<Truth>,
}

impl SpikeFile {
    /// Opens `path` and seeks to plane `start_plane`. A file without a whole plane, or
    /// `start_plane` past its last whole plane, is an error naming the file and the sizes.
    fn open(
        path: &Path,
        geometry: PkuGeometry,
        start_plane: u64,
        plane_period_ns: i64,
        lum_per_rate: f64,
    ) -> Result<Self, FormatError> {
        let open_err = |source| FormatError::Open {
            path: path.to_path_buf(),
            source,
        };
        let mut file = File::open(path).map_err(open_err)?;
        let size = file.metadata().map_err(open_err)?.len();
        if geometry.width == 0 || geometry.height == 0 {
            return Err(FormatError::Unsupported {
                path: path.to_path_buf(),
                what: format!("an empty plane geometry {geometry}"),
            });
        }
        let plane_bytes = geometry.stored_plane_bytes() as u64;
        if size == 0 {
            return Err(FormatError::Empty {
                path: path.to_path_buf(),
            });
        }
        let (planes_in_file, tail_bytes) = (size / plane_bytes, size % plane_bytes);
        if planes_in_file == 0 {
            return Err(FormatError::ResolutionMismatch {
                path: path.to_path_buf(),
                size,
                plane_bytes,
                geometry: geometry.to_string(),
                whole_planes: 0,
                remainder: tail_bytes,
            });
        }
        if start_plane >= planes_in_file {
            return Err(FormatError::Unsupported {
                path: path.to_path_buf(),
                what: format!(
                    "start plane {start_plane}: the file holds {planes_in_file} whole planes of \
                     {geometry} ({plane_bytes} bytes each, {size} bytes in all)"
                ),
            });
        }
        let skip_bytes = start_plane * plane_bytes;
        file.seek(SeekFrom::Start(skip_bytes))
            .map_err(|source| FormatError::Io {
                path: path.to_path_buf(),
                offset: skip_bytes,
                source,
            })?;
        let t_first_ns = i64::try_from(start_plane)
            .ok()
            .and_then(|k| k.checked_mul(plane_period_ns))
            .ok_or_else(|| FormatError::Unsupported {
                path: path.to_path_buf(),
                what: format!(
                    "start plane {start_plane} at {plane_period_ns} ns a plane overflows i64 ns"
                ),
            })?;
        let opts = PkuOptions {
            geometry,
            plane_period_ns,
            t_first_ns,
        };
        Ok(SpikeFile {
            reader: PkuReader::from_reader(file, path, &opts)?,
            path: path.to_path_buf(),
            geometry,
            start_plane,
            skip_bytes,
            planes_in_file,
            tail_bytes,
            plane_period_ns,
            lum_per_rate,
            truth: None,
        })
    }

    /// Time of the start plane: the clock of a paced playback starts there.
    fn start_time_ns(&self) -> i64 {
        self.reader.options().t_first_ns
    }

    /// Whole planes from the start plane to the end of the file.
    fn planes_left(&self) -> u64 {
        self.planes_in_file - self.start_plane
    }

    /// The next (up to) `n` planes as chunk `seq`, or `None` at the end of the file. Errors
    /// (a trailing partial plane, I/O) come after the whole planes before them, with offsets
    /// counted from the start of the file.
    fn next_chunk(&mut self, n: usize, seq: u64) -> Result<Option<SpikeChunk>, FormatError> {
        match self.reader.next_chunk(n) {
            Ok(Some(mut chunk)) => {
                // The reader counts planes from where it started.
                chunk.first_plane += self.start_plane;
                chunk.seq = seq;
                chunk.lum_per_rate = Some(self.lum_per_rate);
                Ok(Some(chunk))
            }
            Ok(None) => Ok(None),
            Err(e) => Err(self.in_file(e)),
        }
    }

    /// The reader counts from the start plane; errors count from the start of the file.
    fn in_file(&self, e: FormatError) -> FormatError {
        match e {
            FormatError::PartialPlane {
                path,
                size,
                plane_bytes,
                geometry,
                whole_planes,
                tail_offset,
                tail_bytes,
            } => FormatError::PartialPlane {
                path,
                size: size + self.skip_bytes,
                plane_bytes,
                geometry,
                whole_planes: whole_planes + self.start_plane,
                tail_offset: tail_offset + self.skip_bytes,
                tail_bytes,
            },
            FormatError::Io {
                path,
                offset,
                source,
            } => FormatError::Io {
                path,
                offset: offset + self.skip_bytes,
                source,
            },
            other => other,
        }
    }
}

/// Camera time at which the chunk's last plane is read out, from the start of the first plane's
/// integration (plane `k` integrates `((k - 1) T, k T]`).
fn chunk_due_ns(chunk: &SpikeChunk) -> i64 {
    let planes = chunk.first_plane.saturating_add(chunk.n_planes as u64);
    i64::try_from(planes)
        .unwrap_or(i64::MAX)
        .saturating_mul(chunk.plane_period_ns)
}

fn main() -> eyre::Result<()> {
    node::init_logging();
    let args: Args = node::parse_config("spike-source")?;
    let source = open_source(&args)?;
    let (node, events) = DoraNode::init_from_env()?;
    node::run_on_rayon("spike-source", || run(node, events, source, &args))
}

fn run(node: DoraNode, events: EventStream, source: Source, args: &Args) -> eyre::Result<()> {
    match source {
        Source::Scene(cam) => simulate(node, events, *cam, args),
        Source::File(file) => play(node, events, *file, args),
    }
}

/// Streams the recording: whole planes first, then the end marker, whatever happened.
fn play(
    mut node: DoraNode,
    mut events: EventStream,
    mut file: SpikeFile,
    args: &Args,
) -> eyre::Result<()> {
    let spikes = output("spikes");
    let planes = args
        .max_planes
        .map_or(file.planes_left(), |m| m.min(file.planes_left()));
    tracing::info!(
        file = %file.path.display(),
        geometry = %file.geometry,
        planes_in_file = file.planes_in_file,
        start_plane = file.start_plane,
        planes,
        period_ns = file.plane_period_ns,
        lum_per_rate = file.lum_per_rate,
        pace = ?args.pace,
        "playing a spike recording"
    );
    if file.tail_bytes > 0 && args.max_planes.is_none_or(|m| m >= file.planes_left()) {
        tracing::warn!(
            file = %file.path.display(),
            tail_bytes = file.tail_bytes,
            "the file is not a whole number of planes: it will end in a partial plane"
        );
    }
    let pacer = Pacer::start(args.pace);
    let (mut seq, mut sent) = (0u64, 0u64);
    let mut failure = None;
    let gt_out = output("ground_truth");
    let mut gt_seq = 0u64;
    loop {
        let n = match args.max_planes {
            Some(max) if sent >= max => break,
            Some(max) => (max - sent).min(u64::from(args.chunk_planes)),
            None => u64::from(args.chunk_planes),
        } as usize;
        if stop_requested(&mut events) {
            break;
        }
        match file.next_chunk(n, seq) {
            Ok(Some(chunk)) => {
                pacer.wait_until(chunk_due_ns(&chunk).saturating_sub(file.start_time_ns()));
                send(&mut node, &spikes, &chunk)?;
                seq += 1;
                sent += chunk.n_planes as u64;
                if let Some(truth) = &mut file.truth {
                    let first = chunk.first_plane;
                    let planes = first..first + chunk.n_planes as u64;
                    let time = |k: u64| chunk.plane_time_ns((k - first) as usize);
                    match truth.frames_in(planes, time, chunk.height, chunk.width) {
                        Ok(frames) => {
                            for (t_ref_ns, data) in frames {
                                let frame = Frame {
                                    kind: FrameKind::GroundTruth,
                                    method: "ground-truth".into(),
                                    t_ref_ns,
                                    compute_ns: 0,
                                    seq: gt_seq,
                                    data,
                                };
                                send(&mut node, &gt_out, &frame)?;
                                gt_seq += 1;
                            }
                        }
                        Err(e) => {
                            tracing::error!("{e}; no more ground truth is sent");
                            file.truth = None;
                            failure = Some(eyre::eyre!(e));
                        }
                    }
                }
            }
            Ok(None) => break,
            Err(e @ FormatError::PartialPlane { .. }) => {
                tracing::error!("{e}; the stream ends after the whole planes");
                break;
            }
            Err(e) => {
                tracing::error!("{e}; the stream ends after the planes read before it");
                failure = Some(eyre::Report::new(e));
                break;
            }
        }
    }
    send_end::<SpikeChunk>(&mut node, &spikes, seq)?;
    if args.truth.is_some() {
        send_end::<Frame>(&mut node, &gt_out, gt_seq)?;
    }
    tracing::info!(
        chunks = seq,
        planes = sent,
        ground_truth = gt_seq,
        "spike recording played"
    );
    if let Some(Truth::Aps(aps)) = &file.truth
        && aps.skipped_before > 0
    {
        tracing::info!(
            frames = aps.skipped_before,
            "APS frames before the first plane played were passed over"
        );
    }
    match failure {
        Some(e) => Err(e).wrap_err("spike-source: the recording could not be read to its end"),
        None => Ok(()),
    }
}

fn simulate(
    mut node: DoraNode,
    mut events: EventStream,
    mut cam: SpikeCamera,
    args: &Args,
) -> eyre::Result<()> {
    let spikes = output("spikes");
    let gt_out = output("ground_truth");
    let total = args.max_planes.unwrap_or_else(|| cam.total_planes());
    tracing::info!(
        planes = total,
        period_ns = cam.period_ns(),
        render_step = cam.render_step(),
        pace = ?args.pace,
        "spike camera started"
    );
    let pacer = Pacer::start(args.pace);
    let (mut seq, mut gt_seq) = (0u64, 0u64);
    while cam.tick() < total {
        if stop_requested(&mut events) {
            break;
        }
        let n = (total - cam.tick()).min(u64::from(args.chunk_planes)) as usize;
        let first = cam.tick();
        let chunk: SpikeChunk = cam.next_chunk(n, seq);
        pacer.wait_until(chunk_due_ns(&chunk));
        send(&mut node, &spikes, &chunk)?;
        seq += 1;
        if args.gt_every_planes > 0 {
            let step = args.gt_every_planes;
            let mut k = first.div_ceil(step) * step;
            while k < first + n as u64 {
                let frame = Frame {
                    kind: FrameKind::GroundTruth,
                    method: "ground-truth".into(),
                    t_ref_ns: cam.plane_time_ns(k),
                    compute_ns: 0,
                    seq: gt_seq,
                    data: cam.ground_truth(k),
                };
                send(&mut node, &gt_out, &frame)?;
                gt_seq += 1;
                k += step;
            }
        }
    }
    send_end::<SpikeChunk>(&mut node, &spikes, seq)?;
    if args.gt_every_planes > 0 {
        send_end::<Frame>(&mut node, &gt_out, gt_seq)?;
    }
    tracing::info!(chunks = seq, ground_truth = gt_seq, "spike camera finished");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use dora_node_api::integration_testing::OutputJson;
    use neuspike_formats::pku::PkuWriter;
    use neuspike_schemas::bytes_per_plane;
    use neuspike_schemas::testing::{CannedInputs, output_ids, payload_len};
    use std::time::{Duration, Instant};

    fn args(extra: &[&str]) -> Args {
        Args::try_parse_from(std::iter::once("spike-source").chain(extra.iter().copied())).unwrap()
    }

    /// Plays `args` through `run` on a testing node; returns what it sent.
    fn play_args(args: &Args) -> Vec<OutputJson> {
        let source = open_source(args).unwrap();
        let dir = tempfile::tempdir().unwrap();
        CannedInputs::new(dir.path())
            .run(|node, events| run(node, events, source, args))
            .unwrap()
    }

    fn payload_bytes(o: &OutputJson) -> Vec<u8> {
        o["data"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| u8::try_from(v.as_u64().unwrap()).unwrap())
            .collect()
    }

    /// `n` planes of `w x h` in the pipeline layout: pseudo-random, padding bits clear.
    fn planes(n: usize, w: usize, h: usize, mut s: u64) -> Vec<u8> {
        let per = bytes_per_plane(w, h);
        let mut bits: Vec<u8> = (0..n * per)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                s as u8
            })
            .collect();
        let pad = per * 8 - w * h;
        if pad > 0 {
            for p in bits.chunks_exact_mut(per) {
                p[per - 1] &= 0xFF >> pad;
            }
        }
        bits
    }

    /// Writes `bits` as a PKU file (plus `extra` stray bytes) and returns its path.
    fn write_dat(dir: &Path, g: PkuGeometry, bits: &[u8], extra: &[u8]) -> PathBuf {
        let path = dir.join("planes.dat");
        let mut w = PkuWriter::new(Vec::new(), &path, g).unwrap();
        w.write_planes(bits).unwrap();
        let (mut bytes, _) = w.finish().unwrap();
        bytes.extend_from_slice(extra);
        std::fs::write(&path, bytes).unwrap();
        path
    }

    #[test]
    fn chunks_ground_truth_and_end_markers() {
        let args = args(&[
            "--scene",
            "bright-static",
            "--width",
            "40",
            "--height",
            "25",
            "--chunk-planes",
            "20",
            "--gt-every-planes",
            "20",
            "--max-planes",
            "50",
        ]);
        let out = play_args(&args);
        let ids = output_ids(&out);
        // 50 planes: chunks of 20, 20, 10; truth at planes 0, 20, 40.
        assert_eq!(ids.iter().filter(|i| *i == "spikes").count(), 4);
        assert_eq!(ids.iter().filter(|i| *i == "ground_truth").count(), 4);
        let spikes: Vec<usize> = out
            .iter()
            .filter(|o| o["id"] == "spikes")
            .map(payload_len)
            .collect();
        let per = bytes_per_plane(40, 25);
        assert_eq!(spikes, vec![20 * per, 20 * per, 10 * per, 0]);
    }

    #[test]
    fn a_recording_played_from_its_middle_keeps_its_clock_and_its_truth() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (16, 4);
        let path = write_dat(dir.path(), PkuGeometry::new(w, h), &planes(9, w, h, 3), &[]);
        let truth = dir.path().join("gt");
        std::fs::create_dir(&truth).unwrap();
        let list = "0 0 a.png\n4 4000000 b.png\n8 8000000 c.png\n";
        std::fs::write(truth.join("timestamps.txt"), list).unwrap();
        for (name, v) in [("a.png", 0u16), ("b.png", 30_000), ("c.png", 60_000)] {
            image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(16, 4, image::Luma([v]))
                .save(truth.join(name))
                .unwrap();
        }
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-width",
            "16",
            "--file-height",
            "4",
            "--start-plane",
            "2",
            "--chunk-planes",
            "4",
            "--rate-hz",
            "1000",
            "--truth",
            truth.to_str().unwrap(),
        ]);
        let out = play_args(&a);
        let gt: Vec<&OutputJson> = out.iter().filter(|o| o["id"] == "ground_truth").collect();
        // Planes 2..9 are played: the truth of planes 4 and 8, at their times, then the marker.
        assert_eq!(gt.len(), 3, "{out:?}");
        // Told apart by their levels: a.png (plane 0, before the start) is not sent.
        let level = |o: &OutputJson| o["data"][0].as_f64().unwrap();
        assert!(
            (level(gt[0]) - 30_000.0 / 65_535.0).abs() < 1e-6,
            "{:?}",
            gt[0]
        );
        assert!((level(gt[1]) - 60_000.0 / 65_535.0).abs() < 1e-6);
        assert_eq!(payload_len(gt[0]), 16 * 4);
        assert_eq!(payload_len(gt[2]), 0, "end-of-stream marker");
    }

    #[test]
    fn a_wrong_key_is_named() {
        let e = Args::try_parse_from(["spike-source", "--rate-hz", "fast"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("rate-hz") && e.contains("fast"), "{e}");
        let e = Args::try_parse_from(["spike-source", "--sceen", "x"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("--sceen"), "{e}");
    }

    #[test]
    fn file_arguments_are_checked() {
        let bad = |a: &[&str]| {
            Args::try_parse_from(std::iter::once("spike-source").chain(a.iter().copied()))
                .unwrap_err()
                .to_string()
        };
        let e = bad(&["--file", "a.dat", "--scene", "bright-slow"]);
        assert!(e.contains("--scene") && e.contains("--file"), "{e}");
        let e = bad(&["--file", "a.dat", "--gt-every-planes", "20"]);
        assert!(e.contains("--gt-every-planes"), "{e}");
        let e = bad(&["--file", "a.dat", "--width", "40"]);
        assert!(e.contains("--width") && e.contains("--file"), "{e}");
        let e = bad(&["--start-plane", "3"]);
        assert!(e.contains("--file"), "{e}");
        let e = bad(&["--file", "a.dat", "--head-columns", "8"]);
        assert!(e.contains("head-columns") && e.contains('8'), "{e}");
        let e = bad(&["--file", "a.dat", "--pace", "slow"]);
        assert!(e.contains("pace") && e.contains("slow"), "{e}");
        // Defaults alone do not need --file.
        let a = args(&[]);
        assert!(a.file.is_none());
        assert_eq!((a.file_width, a.file_height, a.head_columns), (400, 250, 0));
        assert_eq!(a.pace, Pace::Fast);
    }

    #[test]
    fn bad_files_are_named_before_any_message() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.dat");
        let a = args(&["--file", missing.to_str().unwrap()]);
        let e = format!("{:#}", open_source(&a).err().unwrap());
        assert!(e.contains("missing.dat"), "{e}");

        let g = PkuGeometry::new(16, 4);
        let path = write_dat(dir.path(), g, &planes(3, 16, 4, 1), &[]);
        let p = path.to_str().unwrap();
        // 24-byte file, 12,500-byte planes: not even one plane.
        let e = format!("{:#}", open_source(&args(&["--file", p])).err().unwrap());
        assert!(e.contains("planes.dat") && e.contains("24 bytes"), "{e}");
        let e = format!(
            "{:#}",
            open_source(&args(&[
                "--file",
                p,
                "--file-width",
                "16",
                "--file-height",
                "4",
                "--start-plane",
                "3"
            ]))
            .err()
            .unwrap()
        );
        assert!(
            e.contains("start plane 3") && e.contains("3 whole planes"),
            "{e}"
        );
        let e = format!(
            "{:#}",
            open_source(&args(&["--file", p, "--lum-per-rate", "0"]))
                .err()
                .unwrap()
        );
        assert!(e.contains("`lum-per-rate` = 0"), "{e}");
    }

    #[test]
    fn plays_a_written_file_byte_exact() {
        let dir = tempfile::tempdir().unwrap();
        // Odd width: the reader's bit-by-bit path; 7 planes in chunks of 3.
        let (w, h) = (13, 5);
        let bits = planes(7, w, h, 42);
        let path = write_dat(dir.path(), PkuGeometry::new(w, h), &bits, &[]);
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-width",
            "13",
            "--file-height",
            "5",
            "--chunk-planes",
            "3",
        ]);
        let out = play_args(&a);
        assert_eq!(output_ids(&out), vec!["spikes"; 4]);
        let per = bytes_per_plane(w, h);
        let sent: Vec<Vec<u8>> = out.iter().map(payload_bytes).collect();
        assert_eq!(sent[0], bits[..3 * per]);
        assert_eq!(sent[1], bits[3 * per..6 * per]);
        assert_eq!(sent[2], bits[6 * per..]);
        assert!(sent[3].is_empty(), "end-of-stream marker");

        // The headers `run` sends: the same numbering as the simulator's.
        let Source::File(mut f) = open_source(&a).unwrap() else {
            panic!("a file source")
        };
        let mut seq = 0;
        let mut first = 0;
        while let Some(c) = f.next_chunk(3, seq).unwrap() {
            assert_eq!(
                (c.seq, c.first_plane, c.width, c.height),
                (seq, first, w, h)
            );
            assert_eq!(c.t_first_ns, first as i64 * 50_000);
            assert_eq!(c.plane_period_ns, 50_000);
            assert_eq!(c.lum_per_rate, Some(DEFAULT_FILE_LUM_PER_RATE));
            seq += 1;
            first += c.n_planes as u64;
        }
        assert_eq!((seq, first), (3, 7));
    }

    #[test]
    fn start_max_rate_head_columns_and_calibration() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (400, 2);
        let bits = planes(9, w, h, 5);
        let path = write_dat(dir.path(), PkuGeometry::with_head(w, h), &bits, &[]);
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-height",
            "2",
            "--head-columns",
            "16",
            "--start-plane",
            "2",
            "--max-planes",
            "5",
            "--chunk-planes",
            "4",
            "--rate-hz",
            "1000",
            "--lum-per-rate",
            "2.5",
        ]);
        let out = play_args(&a);
        let per = bytes_per_plane(w, h);
        let sent: Vec<Vec<u8>> = out.iter().map(payload_bytes).collect();
        assert_eq!(sent.len(), 3);
        assert_eq!(sent[0], bits[2 * per..6 * per]);
        assert_eq!(sent[1], bits[6 * per..7 * per]);
        assert!(sent[2].is_empty());

        let Source::File(mut f) = open_source(&a).unwrap() else {
            panic!("a file source")
        };
        let c = f.next_chunk(4, 0).unwrap().unwrap();
        // Planes keep their number and time in the file, so that events and ground truth
        // recorded with it still line up.
        assert_eq!(
            (c.first_plane, c.t_first_ns, c.plane_period_ns),
            (2, 2_000_000, 1_000_000)
        );
        assert_eq!(f.start_time_ns(), 2_000_000);
        assert_eq!(c.lum_per_rate, Some(2.5));
        let c = f.next_chunk(4, 1).unwrap().unwrap();
        assert_eq!((c.seq, c.first_plane, c.t_first_ns), (1, 6, 6_000_000));
    }

    #[test]
    fn a_truncated_file_delivers_its_whole_planes_then_ends() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (16, 4);
        let g = PkuGeometry::new(w, h);
        let per = bytes_per_plane(w, h);
        let bits = planes(5, w, h, 9);
        let path = write_dat(dir.path(), g, &bits, &[0xAB; 3]);
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-width",
            "16",
            "--file-height",
            "4",
            "--chunk-planes",
            "2",
        ]);
        let out = play_args(&a);
        let sent: Vec<Vec<u8>> = out.iter().map(payload_bytes).collect();
        assert_eq!(sent.len(), 4, "chunks of 2, 2, 1 planes and the marker");
        assert_eq!(sent[..3].concat(), bits);
        assert!(sent[3].is_empty());

        // The error names the file and the partial plane's offset from the start of the file,
        // also when playing starts past the first plane.
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-width",
            "16",
            "--file-height",
            "4",
            "--start-plane",
            "1",
        ]);
        let Source::File(mut f) = open_source(&a).unwrap() else {
            panic!("a file source")
        };
        let c = f.next_chunk(10, 0).unwrap().unwrap();
        assert_eq!(c.bits, bits[per..]);
        let e = f.next_chunk(10, 1).unwrap_err();
        let msg = e.to_string();
        assert!(
            matches!(
                e,
                FormatError::PartialPlane {
                    tail_offset: 40,
                    tail_bytes: 3,
                    whole_planes: 5,
                    size: 43,
                    ..
                }
            ),
            "{msg}"
        );
        assert!(
            msg.contains("planes.dat") && msg.contains("at byte 40"),
            "{msg}"
        );
    }

    #[test]
    fn realtime_pace_follows_the_plane_rate() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_dat(
            dir.path(),
            PkuGeometry::new(8, 2),
            &planes(20, 8, 2, 3),
            &[],
        );
        let a = args(&[
            "--file",
            path.to_str().unwrap(),
            "--file-width",
            "8",
            "--file-height",
            "2",
            "--chunk-planes",
            "5",
            "--rate-hz",
            "1000",
            "--pace",
            "realtime",
        ]);
        let start = Instant::now();
        let out = play_args(&a);
        // 20 planes at 1 kHz: the last chunk is due 20 ms after the start.
        assert!(start.elapsed() >= Duration::from_millis(20));
        assert_eq!(out.len(), 5);
    }

    #[test]
    fn plays_the_real_vidar_recording() {
        let Some(path) = neuspike_schemas::testing::real_recording("vidar-car-400x250.dat") else {
            return;
        };
        let a = args(&["--file", path.to_str().unwrap(), "--chunk-planes", "32"]);
        let out = play_args(&a);
        // 200 planes of 12,500 bytes: six chunks of 32, one of 8, and the marker.
        let lens: Vec<usize> = out.iter().map(payload_len).collect();
        assert_eq!(lens, [&[32 * 12_500; 6][..], &[8 * 12_500, 0]].concat());
        let sent: Vec<u8> = out.iter().flat_map(payload_bytes).collect();
        let spikes: u64 = sent.iter().map(|b| u64::from(b.count_ones())).sum();
        assert_eq!(spikes, 7_324_316, "the README's spike count");
        // Byte-exact against the file, rows flipped upright (400 pixels = 50 bytes a row).
        let raw = std::fs::read(&path).unwrap();
        for (stored, plane) in raw.chunks_exact(12_500).zip(sent.chunks_exact(12_500)) {
            for y in 0..250 {
                let src = (249 - y) * 50;
                assert_eq!(plane[y * 50..y * 50 + 50], stored[src..src + 50]);
            }
        }
    }
}
