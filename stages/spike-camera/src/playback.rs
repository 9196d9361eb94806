//! The spike source's stage: the simulated camera or a PKU `.dat` recording, played a chunk of
//! planes at a time, with the ground truth that falls in each chunk.
//!
//! A recording is streamed `chunk_planes` planes at a time, never loaded whole, and its planes
//! go out as the simulator's do: chunks numbered by `seq` from 0, planes numbered by their place
//! in the file (the first one sent is `start_plane`), plane `k` stamped `k * T`. Played from its
//! middle, a recording keeps its clock, so that an event file and ground truth recorded with it
//! (both counted from the recording's start) still line up. A file that ends in a partial plane
//! (truncated, or the wrong geometry) has its whole planes played, then the partial plane is
//! logged with the file and its byte offset, and the stream ends.

use std::fs::File;
use std::io::{Seek, SeekFrom};
use std::path::{Path, PathBuf};

use neuspike_formats::FormatError;
use neuspike_formats::pku::{HEAD_COLUMNS, PkuGeometry, PkuOptions, PkuReader};
use neuspike_scene::{Scene, SceneError};
use neuspike_schemas::{Frame, FrameKind, SpikeChunk, bytes_per_plane};
use neuspike_stage::{Flow, Msg, MsgType, Outbox, Pacer, Port, Stage, Tallies};

use crate::truth::Truth;
use crate::{CameraConfig, CameraError, ConfigError, SpikeCamera};

/// Luminance per unit firing rate sent with the planes of a recording when the settings give
/// none: TFP frames show the firing rate (0.366 on average in a Vidar street recording).
pub const DEFAULT_FILE_LUM_PER_RATE: f64 = 1.0;

/// The spike source's settings (the node's `args:`): the scene or the recording, the chunking,
/// and the camera model.
#[derive(Clone, Debug, clap::Args)]
pub struct SpikeSourceConfig {
    /// Built-in scene name or path of a scene YAML file.
    #[arg(long, default_value = "bright-slow", conflicts_with = "file")]
    pub scene: String,
    /// Play this PKU spike `.dat` recording instead of simulating a scene (its size is
    /// `--file-width`/`--file-height`, not the simulator's `--width`/`--height`).
    #[arg(long, conflicts_with_all = ["width", "height"])]
    pub file: Option<PathBuf>,
    /// Width of the recording's planes in pixels (head columns not included).
    #[arg(long, default_value_t = 400, requires = "file",
          value_parser = clap::value_parser!(u16).range(1..))]
    pub file_width: u16,
    /// Height of the recording's planes in pixels.
    #[arg(long, default_value_t = 250, requires = "file",
          value_parser = clap::value_parser!(u16).range(1..))]
    pub file_height: u16,
    /// Extra columns stored at the end of each row of the recording and dropped: 0 or 16.
    #[arg(long, default_value_t = 0, requires = "file", value_parser = parse_head_columns)]
    pub head_columns: usize,
    /// First plane of the recording to play (the planes before it are skipped by seeking).
    #[arg(long, default_value_t = 0, requires = "file")]
    pub start_plane: u64,
    /// Ground truth recorded with the file: a folder whose `timestamps.txt` lists `plane t_ns
    /// file` (as `neuspike simulate` writes `ground-truth/`), each listed plane that is played
    /// sending its PNG on `ground_truth` at that plane's time; or an AEDAT 4 file whose APS
    /// frames are sent at their own times (on the spike clock) as the planes around them play.
    #[arg(long, requires = "file")]
    pub truth: Option<PathBuf>,
    /// Luminance per unit firing rate sent with the recording's planes (default 1.0).
    #[arg(long, requires = "file")]
    pub lum_per_rate: Option<f64>,
    /// Planes per output message.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub chunk_planes: u32,
    /// Emit the ground-truth frame at every plane whose index is a multiple of this (0 = never).
    #[arg(long, default_value_t = 0, conflicts_with = "file")]
    pub gt_every_planes: u64,
    /// Stop after this many planes (default: the scene's duration, or the whole recording).
    #[arg(long)]
    pub max_planes: Option<u64>,
    /// Simulate the first N planes once (rounded up to whole chunks), then send them again and
    /// again, numbered and timed as a live camera's: a camera that costs next to nothing to run,
    /// for timing the stages after it (a real camera does not simulate). A static scene repeats
    /// without a seam in its light; the spikes restart their phase at each turn.
    #[arg(long, conflicts_with_all = ["file", "gt_every_planes"],
          value_parser = clap::value_parser!(u64).range(1..=MAX_REPEAT_PLANES))]
    pub repeat_planes: Option<u64>,
    /// The spike camera model's settings.
    #[command(flatten)]
    pub camera: CameraConfig,
}

/// The most planes `--repeat-planes` holds in memory: 2^16 (800 MiB of 400x250 planes).
pub const MAX_REPEAT_PLANES: u64 = 1 << 16;

fn parse_head_columns(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Ok(0),
        Ok(n) if n == HEAD_COLUMNS => Ok(n),
        _ => Err(format!("`{s}` is not 0 or {HEAD_COLUMNS}")),
    }
}

/// Why the spike source could not start or could not play to the end.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// A camera setting is out of its domain.
    #[error("spike-source: bad camera settings")]
    Config(#[from] ConfigError),
    /// The camera could not be made (a setting or its noise profile).
    #[error("spike-source: bad camera settings")]
    Camera(#[from] CameraError),
    /// The scene could not be loaded.
    #[error("spike-source: cannot load the scene")]
    Scene(#[from] SceneError),
    /// The recording could not be opened, or failed part-way.
    #[error("spike-source: cannot play the recording")]
    Format(#[from] FormatError),
    /// The ground truth could not be opened or read.
    #[error("spike-source: {0}")]
    Truth(String),
    /// A setting is invalid.
    #[error("spike-source: `{name}` = {value} is invalid: {reason}")]
    Param {
        /// The setting.
        name: &'static str,
        /// Its value.
        value: String,
        /// What it must satisfy.
        reason: &'static str,
    },
}

/// One step of a source: a chunk of planes, the camera time at which its last plane is read
/// out (from the start of the stream), and the ground truth that falls within it.
#[derive(Debug)]
pub struct SpikeStep {
    /// The planes.
    pub chunk: SpikeChunk,
    /// When the camera has read the chunk's last plane, ns from the stream's start.
    pub due_ns: i64,
    /// Ground-truth frames within the chunk, in time order.
    pub truth: Vec<Frame>,
}

/// Where the planes come from.
pub enum SpikeSource {
    /// The simulated camera looking at a scene.
    Scene(Box<ScenePlayback>),
    /// A recording.
    File(Box<FilePlayback>),
}

impl SpikeSource {
    /// Checks the settings and opens the scene or the file (and its ground truth).
    pub fn open(cfg: &SpikeSourceConfig) -> Result<Self, SourceError> {
        let period_ns = cfg.camera.validate()?;
        let Some(path) = &cfg.file else {
            let cam = SpikeCamera::new(Scene::load(&cfg.scene)?, cfg.camera.clone())?;
            let mut playback =
                ScenePlayback::new(cam, cfg.max_planes, cfg.chunk_planes, cfg.gt_every_planes);
            if let Some(planes) = cfg.repeat_planes {
                playback.repeat(planes);
            }
            return Ok(SpikeSource::Scene(Box::new(playback)));
        };
        let lum_per_rate = cfg.lum_per_rate.unwrap_or(DEFAULT_FILE_LUM_PER_RATE);
        if !(lum_per_rate.is_finite() && lum_per_rate > 0.0) {
            return Err(SourceError::Param {
                name: "lum-per-rate",
                value: lum_per_rate.to_string(),
                reason: "must be finite and > 0",
            });
        }
        let geometry = PkuGeometry {
            width: cfg.file_width.into(),
            height: cfg.file_height.into(),
            head_columns: cfg.head_columns,
        };
        let mut file = SpikeFile::open(path, geometry, cfg.start_plane, period_ns, lum_per_rate)?;
        if let Some(dir) = &cfg.truth {
            file.truth = Some(Truth::open(dir).map_err(SourceError::Truth)?);
        }
        Ok(SpikeSource::File(Box::new(FilePlayback {
            file,
            max_planes: cfg.max_planes,
            chunk_planes: cfg.chunk_planes,
            seq: 0,
            sent: 0,
            gt_seq: 0,
            failure: None,
        })))
    }

    /// Whether the source sends ground truth.
    pub fn sends_truth(&self) -> bool {
        match self {
            SpikeSource::Scene(s) => s.gt_every > 0,
            SpikeSource::File(f) => f.file.truth.is_some(),
        }
    }

    /// Goes on from plane `plane` (counted from the first plane played), numbering what it sends
    /// as if every plane before had been sent: what a source restarted mid-run does, so that its
    /// consumers count the planes it missed as a gap. A simulated camera jumps there; a recording
    /// is read up to there. Returns the first plane it will send.
    ///
    /// # Errors
    /// The recording could not be read up to there.
    pub fn skip_to(&mut self, plane: u64) -> Result<u64, SourceError> {
        match self {
            SpikeSource::Scene(s) => Ok(s.skip_to(plane)),
            SpikeSource::File(f) => {
                while f.sent < plane {
                    if f.next_step()?.is_none() {
                        break;
                    }
                }
                Ok(f.sent)
            }
        }
    }

    /// Logs what is about to be played.
    pub fn log_start(&self) {
        match self {
            SpikeSource::Scene(s) => s.log_start(),
            SpikeSource::File(f) => f.log_start(),
        }
    }

    /// The next step, or `None` at the end of the stream. An error ends the stream after the
    /// steps before it.
    pub fn next_step(&mut self) -> Result<Option<SpikeStep>, SourceError> {
        match self {
            SpikeSource::Scene(s) => Ok(s.next_step()),
            SpikeSource::File(f) => f.next_step(),
        }
    }

    /// Logs what was played; an error the stream survived (the ground truth failing part-way)
    /// is returned now.
    pub fn finish(self) -> Result<(), SourceError> {
        match self {
            SpikeSource::Scene(s) => {
                tracing::info!(
                    chunks = s.seq,
                    ground_truth = s.gt_seq,
                    "spike camera finished"
                );
                Ok(())
            }
            SpikeSource::File(f) => f.finish(),
        }
    }
}

/// The simulated camera, a chunk at a time, with ground truth at every `gt_every`-th plane.
pub struct ScenePlayback {
    cam: SpikeCamera,
    total: u64,
    chunk_planes: u32,
    gt_every: u64,
    seq: u64,
    gt_seq: u64,
    tape: Option<Tape>,
}

/// The first planes of a camera, simulated once and played again and again
/// ([`ScenePlayback::repeat`]).
struct Tape {
    /// The first chunk's header: geometry, clock and calibration.
    header: SpikeChunk,
    /// `planes` packed planes.
    bits: Vec<u8>,
    /// Planes on the tape (at least one).
    planes: u64,
    /// The next plane to send, counted from the first plane played.
    next: u64,
}

impl ScenePlayback {
    /// Plays `cam` for `max_planes` (default: the scene's duration).
    pub fn new(
        cam: SpikeCamera,
        max_planes: Option<u64>,
        chunk_planes: u32,
        gt_every: u64,
    ) -> Self {
        let total = max_planes.unwrap_or_else(|| cam.total_planes());
        ScenePlayback {
            cam,
            total,
            chunk_planes: chunk_planes.max(1),
            gt_every,
            seq: 0,
            gt_seq: 0,
            tape: None,
        }
    }

    /// Simulates the next `planes` planes (rounded up to whole chunks, at least one chunk, at
    /// most the planes to play) now, and from then on sends them in a loop instead of simulating
    /// (`--repeat-planes`). Ground truth is not sent while repeating.
    pub fn repeat(&mut self, planes: u64) {
        let chunk = u64::from(self.chunk_planes);
        let planes = planes
            .max(1)
            .div_ceil(chunk)
            .saturating_mul(chunk)
            .min(self.total.saturating_sub(self.cam.tick()))
            .max(1);
        let first = self.cam.tick();
        let n = usize::try_from(planes).unwrap_or(usize::MAX);
        let taped = self.cam.next_chunk(n, 0);
        self.gt_every = 0;
        self.tape = Some(Tape {
            header: taped.header_only(),
            bits: taped.bits,
            planes,
            next: first,
        });
    }

    fn log_start(&self) {
        tracing::info!(
            planes = self.total,
            period_ns = self.cam.period_ns(),
            render_step = self.cam.render_step(),
            "spike camera started"
        );
    }

    /// Moves to the chunk boundary at or after plane `plane`, numbering chunks and ground truth
    /// as if every plane before had been sent: a camera switched back on (see
    /// [`SpikeCamera::jump_to`]).
    fn skip_to(&mut self, plane: u64) -> u64 {
        let chunk = u64::from(self.chunk_planes);
        let plane = plane.div_ceil(chunk).saturating_mul(chunk);
        self.seq = plane / chunk;
        if let Some(tape) = &mut self.tape {
            tape.next = plane;
            return plane;
        }
        self.cam.jump_to(plane);
        if self.gt_every > 0 {
            self.gt_seq = plane.div_ceil(self.gt_every);
        }
        self.cam.tick()
    }

    /// The next chunk from the tape ([`ScenePlayback::repeat`]).
    fn replay(&mut self) -> Option<SpikeStep> {
        let tape = self.tape.as_mut()?;
        if tape.next >= self.total {
            return None;
        }
        let first = tape.next;
        let n = (self.total - first).min(u64::from(self.chunk_planes));
        let per = bytes_per_plane(tape.header.width, tape.header.height);
        let mut bits = Vec::with_capacity(n as usize * per);
        for k in first..first + n {
            // k % planes < planes <= the tape's planes: in bounds
            let at = (k % tape.planes) as usize * per;
            bits.extend_from_slice(&tape.bits[at..at + per]);
        }
        let chunk = SpikeChunk {
            first_plane: first,
            n_planes: n as usize,
            t_first_ns: self.cam.plane_time_ns(first),
            seq: self.seq,
            bits,
            ..tape.header.header_only()
        };
        tape.next += n;
        self.seq += 1;
        Some(SpikeStep {
            due_ns: chunk_due_ns(&chunk),
            chunk,
            truth: Vec::new(),
        })
    }

    /// The next chunk and the ground truth at its planes, or `None` after the last plane.
    pub fn next_step(&mut self) -> Option<SpikeStep> {
        if self.tape.is_some() {
            return self.replay();
        }
        let cam = &mut self.cam;
        if cam.tick() >= self.total {
            return None;
        }
        let n = (self.total - cam.tick()).min(u64::from(self.chunk_planes)) as usize;
        let first = cam.tick();
        let chunk: SpikeChunk = cam.next_chunk(n, self.seq);
        self.seq += 1;
        let mut truth = Vec::new();
        if self.gt_every > 0 {
            let step = self.gt_every;
            let mut k = first.div_ceil(step) * step;
            while k < first + n as u64 {
                truth.push(Frame {
                    kind: FrameKind::GroundTruth,
                    method: "ground-truth".into(),
                    t_ref_ns: cam.plane_time_ns(k),
                    compute_ns: 0,
                    chosen: None,
                    budget_ns: None,
                    seq: self.gt_seq,
                    data: cam.ground_truth(k),
                });
                self.gt_seq += 1;
                k += step;
            }
        }
        Some(SpikeStep {
            due_ns: chunk_due_ns(&chunk),
            chunk,
            truth,
        })
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

/// A recording played a chunk at a time, with its recorded ground truth.
pub struct FilePlayback {
    file: SpikeFile,
    max_planes: Option<u64>,
    chunk_planes: u32,
    seq: u64,
    sent: u64,
    gt_seq: u64,
    /// The ground truth failed part-way: reported at the end.
    failure: Option<String>,
}

impl FilePlayback {
    /// The recording.
    pub fn file(&mut self) -> &mut SpikeFile {
        &mut self.file
    }

    fn planes(&self) -> u64 {
        let left = self.file.planes_left();
        self.max_planes.map_or(left, |m| m.min(left))
    }

    fn log_start(&self) {
        let f = &self.file;
        tracing::info!(
            file = %f.path.display(),
            geometry = %f.geometry,
            planes_in_file = f.planes_in_file,
            start_plane = f.start_plane,
            planes = self.planes(),
            period_ns = f.plane_period_ns,
            lum_per_rate = f.lum_per_rate,
            "playing a spike recording"
        );
        if f.tail_bytes > 0 && self.max_planes.is_none_or(|m| m >= f.planes_left()) {
            tracing::warn!(
                file = %f.path.display(),
                tail_bytes = f.tail_bytes,
                "the file is not a whole number of planes: it will end in a partial plane"
            );
        }
    }

    /// The next chunk of the recording and the ground truth within it, or `None` at the end
    /// (the file's, `max_planes`, or a trailing partial plane, which is logged). A ground truth
    /// that fails part-way is logged and no more of it is sent; the planes go on.
    pub fn next_step(&mut self) -> Result<Option<SpikeStep>, SourceError> {
        let n = match self.max_planes {
            Some(max) if self.sent >= max => return Ok(None),
            Some(max) => (max - self.sent).min(u64::from(self.chunk_planes)),
            None => u64::from(self.chunk_planes),
        } as usize;
        let chunk = match self.file.next_chunk(n, self.seq) {
            Ok(Some(chunk)) => chunk,
            Ok(None) => return Ok(None),
            Err(e @ FormatError::PartialPlane { .. }) => {
                tracing::error!("{e}; the stream ends after the whole planes");
                return Ok(None);
            }
            Err(e) => {
                tracing::error!("{e}; the stream ends after the planes read before it");
                return Err(e.into());
            }
        };
        self.seq += 1;
        self.sent += chunk.n_planes as u64;
        let mut truth = Vec::new();
        if let Some(t) = &mut self.file.truth {
            let first = chunk.first_plane;
            let planes = first..first + chunk.n_planes as u64;
            let time = |k: u64| chunk.plane_time_ns((k - first) as usize);
            match t.frames_in(planes, time, chunk.height, chunk.width) {
                Ok(frames) => {
                    for (t_ref_ns, data) in frames {
                        truth.push(Frame {
                            kind: FrameKind::GroundTruth,
                            method: "ground-truth".into(),
                            t_ref_ns,
                            compute_ns: 0,
                            chosen: None,
                            budget_ns: None,
                            seq: self.gt_seq,
                            data,
                        });
                        self.gt_seq += 1;
                    }
                }
                Err(e) => {
                    tracing::error!("{e}; no more ground truth is sent");
                    self.file.truth = None;
                    self.failure = Some(e);
                }
            }
        }
        let due_ns = chunk_due_ns(&chunk).saturating_sub(self.file.start_time_ns());
        Ok(Some(SpikeStep {
            chunk,
            due_ns,
            truth,
        }))
    }

    fn finish(self) -> Result<(), SourceError> {
        tracing::info!(
            chunks = self.seq,
            planes = self.sent,
            ground_truth = self.gt_seq,
            "spike recording played"
        );
        if let Some(Truth::Aps(aps)) = &self.file.truth
            && aps.skipped_before > 0
        {
            tracing::info!(
                frames = aps.skipped_before,
                "APS frames before the first plane played were passed over"
            );
        }
        match self.failure {
            Some(e) => Err(SourceError::Truth(format!(
                "the recording's ground truth could not be read to its end: {e}"
            ))),
            None => Ok(()),
        }
    }
}
/// A PKU `.dat` recording being played from `start_plane` on, a chunk at a time.
pub struct SpikeFile {
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
    pub fn start_time_ns(&self) -> i64 {
        self.reader.options().t_first_ns
    }

    /// Whole planes from the start plane to the end of the file.
    fn planes_left(&self) -> u64 {
        self.planes_in_file - self.start_plane
    }

    /// The next (up to) `n` planes as chunk `seq`, or `None` at the end of the file. Errors
    /// (a trailing partial plane, I/O) come after the whole planes before them, with offsets
    /// counted from the start of the file.
    pub fn next_chunk(&mut self, n: usize, seq: u64) -> Result<Option<SpikeChunk>, FormatError> {
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

/// The spike camera as a source stage: output `spikes` and, when the source makes it,
/// `ground_truth`; each chunk sent when its pace says ([`Pacer`]), stamped with the wall time
/// its camera would have delivered it.
pub struct SpikeSourceStage {
    source: Option<SpikeSource>,
    truth: bool,
    pacer: Pacer,
}

impl SpikeSourceStage {
    /// The stage of `source`, paced by `pacer`.
    pub fn new(source: SpikeSource, pacer: Pacer) -> Self {
        SpikeSourceStage {
            truth: source.sends_truth(),
            source: Some(source),
            pacer,
        }
    }
}

impl Stage for SpikeSourceStage {
    fn name(&self) -> &str {
        "spike-source"
    }

    fn inputs(&self) -> Vec<Port> {
        vec![]
    }

    fn outputs(&self) -> Vec<Port> {
        let mut ports = vec![Port::new("spikes", MsgType::SpikeChunk)];
        if self.truth {
            ports.push(Port::new("ground_truth", MsgType::Frame));
        }
        ports
    }

    fn step(&mut self, out: &mut Outbox) -> eyre::Result<Flow> {
        let Some(source) = self.source.as_mut() else {
            return Ok(Flow::Stop);
        };
        let Some(step) = source.next_step()? else {
            return Ok(Flow::Stop);
        };
        if let Some(due_unix_ns) = self.pacer.wait_until(step.due_ns) {
            out.set_origin(due_unix_ns);
        }
        out.send("spikes", step.chunk);
        for frame in step.truth {
            out.send("ground_truth", frame);
        }
        Ok(Flow::Continue)
    }

    fn on_message(&mut self, _: &str, _: Msg, _: &mut Outbox) -> eyre::Result<Flow> {
        Ok(Flow::Continue)
    }

    fn finish(&mut self, _: &Tallies, _: &mut Outbox) -> eyre::Result<()> {
        match self.source.take() {
            Some(source) => Ok(source.finish()?),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_formats::pku::PkuWriter;

    fn config(file: Option<PathBuf>) -> SpikeSourceConfig {
        SpikeSourceConfig {
            scene: "bright-static".into(),
            file,
            file_width: 16,
            file_height: 4,
            head_columns: 0,
            start_plane: 0,
            truth: None,
            lum_per_rate: None,
            chunk_planes: 20,
            gt_every_planes: 20,
            max_planes: Some(45),
            repeat_planes: None,
            camera: CameraConfig {
                width: 16,
                height: 8,
                ..CameraConfig::default()
            },
        }
    }

    fn steps(source: &mut SpikeSource) -> Vec<SpikeStep> {
        std::iter::from_fn(|| source.next_step().expect("step")).collect()
    }

    /// `--repeat-planes`: the first planes simulated once, then sent in a loop with the clock,
    /// plane numbers and sequence of a live camera, no ground truth; the last chunk short.
    #[test]
    fn a_repeating_camera_sends_its_tape_again_on_the_cameras_clock() {
        let mut cfg = config(None);
        cfg.gt_every_planes = 0;
        cfg.max_planes = Some(105);
        let simulated = steps(&mut SpikeSource::open(&cfg).expect("open"));
        cfg.repeat_planes = Some(25); // rounded up to two chunks of 20
        let mut source = SpikeSource::open(&cfg).expect("open");
        assert!(!source.sends_truth());
        let repeated = steps(&mut source);
        assert_eq!(repeated.len(), simulated.len());
        let per = bytes_per_plane(16, 8);
        let tape: Vec<u8> = simulated[..2]
            .iter()
            .flat_map(|s| s.chunk.bits.clone())
            .collect();
        for (r, s) in repeated.iter().zip(&simulated) {
            let (r, s) = (&r.chunk, &s.chunk);
            assert_eq!(
                (
                    r.seq,
                    r.first_plane,
                    r.n_planes,
                    r.t_first_ns,
                    r.plane_period_ns
                ),
                (
                    s.seq,
                    s.first_plane,
                    s.n_planes,
                    s.t_first_ns,
                    s.plane_period_ns
                )
            );
            assert_eq!(r.lum_per_rate, s.lum_per_rate);
            for i in 0..r.n_planes {
                let k = (r.first_plane as usize + i) % 40;
                assert_eq!(r.plane_bits(i), &tape[k * per..(k + 1) * per], "plane {k}");
            }
        }
        assert_eq!(repeated.last().map(|s| s.chunk.n_planes), Some(5));
        assert!(repeated.iter().all(|s| s.truth.is_empty()));
        // the tape is not all dark: the loop repeats real spikes
        assert!(tape.iter().any(|&b| b != 0));
        // a restarted camera goes on from a plane on the tape's clock
        let mut source = SpikeSource::open(&cfg).expect("open");
        assert_eq!(source.skip_to(50).expect("skip"), 60);
        let next = source.next_step().expect("step").expect("a chunk");
        assert_eq!((next.chunk.seq, next.chunk.first_plane), (3, 60));
        assert_eq!(next.chunk.plane_bits(0), &tape[20 * per..21 * per]);
    }

    #[test]
    fn a_scene_plays_in_chunks_with_truth_at_every_kth_plane() {
        let mut source = SpikeSource::open(&config(None)).expect("scene");
        assert!(source.sends_truth());
        let steps = steps(&mut source);
        let chunks: Vec<(u64, u64, usize)> = steps
            .iter()
            .map(|s| (s.chunk.seq, s.chunk.first_plane, s.chunk.n_planes))
            .collect();
        assert_eq!(chunks, [(0, 0, 20), (1, 20, 20), (2, 40, 5)]);
        let period = steps[0].chunk.plane_period_ns;
        let truth: Vec<(u64, i64)> = steps
            .iter()
            .flat_map(|s| s.truth.iter().map(|f| (f.seq, f.t_ref_ns)))
            .collect();
        assert_eq!(truth, [(0, 0), (1, 20 * period), (2, 40 * period)]);
        // Each chunk is due when its last plane has been read out.
        assert_eq!(steps[2].due_ns, 45 * period);
        assert!(source.finish().is_ok());
    }

    #[test]
    fn a_recording_plays_from_its_start_plane_and_ends_at_its_last_whole_plane() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("planes.dat");
        let geometry = PkuGeometry::new(16, 4);
        let per = bytes_per_plane(16, 4);
        let bits: Vec<u8> = (0..7 * per).map(|i| (i * 37 % 251) as u8).collect();
        let mut w = PkuWriter::new(Vec::new(), &path, geometry).expect("writer");
        w.write_planes(&bits).expect("planes");
        let mut bytes = w.finish().expect("finish").0;
        bytes.extend_from_slice(&[0xAB; 3]); // a partial plane at the end
        std::fs::write(&path, bytes).expect("write");
        let mut cfg = config(Some(path));
        cfg.gt_every_planes = 0;
        cfg.max_planes = None;
        cfg.chunk_planes = 4;
        cfg.start_plane = 2;
        let mut source = SpikeSource::open(&cfg).expect("file");
        assert!(!source.sends_truth());
        let steps = steps(&mut source);
        let chunks: Vec<(u64, u64, usize)> = steps
            .iter()
            .map(|s| (s.chunk.seq, s.chunk.first_plane, s.chunk.n_planes))
            .collect();
        assert_eq!(chunks, [(0, 2, 4), (1, 6, 1)]);
        let played: Vec<u8> = steps.iter().flat_map(|s| s.chunk.bits.clone()).collect();
        assert_eq!(played, bits[2 * per..]);
        assert_eq!(steps[0].chunk.lum_per_rate, Some(DEFAULT_FILE_LUM_PER_RATE));
        // A paced playback's clock starts at the start plane.
        assert_eq!(steps[0].due_ns, 4 * steps[0].chunk.plane_period_ns);
        assert!(source.finish().is_ok());
        cfg.start_plane = 7;
        let e = SpikeSource::open(&cfg)
            .err()
            .expect("past the end")
            .to_string();
        assert!(e.contains("spike-source"), "{e}");
    }
}
