//! `neuspike frames-to-events`: the DVS pixel array run on a sequence of intensity frames, as
//! v2e runs its emulator on video frames, so that the two can be compared on the same input.
//!
//! Input: a `.npy` of float32 `[T, H, W]` intensities (the scene's luminance in `[0, 1]`), frame
//! `k` at `k * dt_ns`, read a frame at a time (two frames of memory, whatever the video's
//! length; a Fortran-order file is read whole). The first frame sets every pixel's reference level; each later frame adds
//! the crossings of the log-intensity path from the frame before, and the noise of that
//! interval, exactly as [`neuspike_event_camera::DvsPixels::step`] does inside the event camera. Output: the events as
//! Event Camera Dataset text (`seconds x y polarity`, 1 ON / 0 OFF, a `width height` first
//! line), and a one-line JSON summary on stdout whose `wall_s` counts only the emulation (the
//! steps and the sorting of each step's events by time), not reading or writing.
//!
//! v2e's parameter names map onto these arguments one for one (docs/camera.md).

use std::path::PathBuf;
use std::time::Instant;

use eyre::{WrapErr, bail, eyre};
use ndarray::{Array3, Axis};
use neuspike_event_camera::{DvsConfig, FrameSteps};
use neuspike_formats::Resolution;
use neuspike_formats::npy::NpyFrames;
use neuspike_formats::text::TextWriter;

/// The `neuspike frames-to-events` arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct FramesToEventsOptions {
    /// Frames: a `.npy` of float32 `[T, H, W]` intensities in `[0, 1]`.
    #[arg(long)]
    pub frames: PathBuf,
    /// Time between two frames, nanoseconds.
    #[arg(long)]
    pub dt_ns: i64,
    /// Output: the events as text (`seconds x y polarity`).
    #[arg(long)]
    pub out: PathBuf,
    /// The light scale the frames are seen at (intensity multiplier before the log).
    #[arg(long, default_value_t = 1.0)]
    pub light_scale: f32,
    /// The pixel array's settings, as the event source takes them (v2e's names in
    /// docs/camera.md); the frames give the size, and the rig and sampling settings do not
    /// apply.
    #[command(flatten)]
    pub dvs: DvsConfig,
}

/// What a run made.
#[derive(Clone, Debug, PartialEq)]
pub struct FramesToEventsSummary {
    /// Frames read.
    pub frames: usize,
    /// Sensor size.
    pub width: usize,
    /// Sensor size.
    pub height: usize,
    /// ON events.
    pub on: u64,
    /// OFF events.
    pub off: u64,
    /// Seconds spent emulating (steps and sorting), reading and writing excluded.
    pub wall_s: f64,
}

impl FramesToEventsSummary {
    /// The summary as one JSON line.
    pub fn json(&self) -> String {
        let fps = if self.wall_s > 0.0 {
            (self.frames.saturating_sub(1)) as f64 / self.wall_s
        } else {
            f64::INFINITY
        };
        format!(
            "{{\"frames\": {}, \"width\": {}, \"height\": {}, \"events\": {}, \"on\": {}, \"off\": {}, \"wall_s\": {:.6}, \"frames_per_s\": {:.1}}}",
            self.frames,
            self.width,
            self.height,
            self.on + self.off,
            self.on,
            self.off,
            self.wall_s,
            fps
        )
    }
}

/// `d` for frames of `width x height`, for `command`: the rig and the sampling (a scene's) are
/// refused by name.
///
/// # Errors
/// A rig or sampling setting is given.
pub fn frames_config(
    d: &DvsConfig,
    width: usize,
    height: usize,
    command: &str,
) -> eyre::Result<DvsConfig> {
    if let Some(name) = d.scene_only_setting() {
        bail!("{command}: --{name} applies to a simulated scene, not to frames");
    }
    Ok(DvsConfig {
        width,
        height,
        ..d.clone()
    })
}

/// The frames of `path`, a float32 `[T, H, W]` `.npy` of at least 2 frames of 1..=65535 pixels
/// a side, and `(T, H, W)`: read a frame at a time, or, in Fortran order (which spreads each
/// frame over the whole file), read whole and every frame checked ([`check_frame`]) before
/// anything is made of them.
///
/// # Errors
/// The file cannot be read, is not such an array, or (Fortran order) holds a bad value.
pub(crate) fn open_frames(path: &std::path::Path) -> eyre::Result<(Frames, (usize, usize, usize))> {
    let name = path.display();
    let reader = NpyFrames::open(path).map_err(|e| eyre!("not a float32 [T, H, W] .npy: {e}"))?;
    let (t, h, w) = reader.shape();
    if t < 2 || h == 0 || w == 0 || h > u16::MAX as usize || w > u16::MAX as usize {
        bail!("{name}: shape [{t}, {h}, {w}]: needs at least 2 frames of 1..=65535 pixels a side");
    }
    if !reader.fortran_order() {
        return Ok((Frames::Stream(reader), (t, h, w)));
    }
    let all: Array3<f32> = ndarray_npy::read_npy(path)
        .map_err(|e| eyre!("{name}: not a float32 [T, H, W] .npy: {e}"))?;
    let all = all.as_standard_layout().into_owned();
    for (k, frame) in all.outer_iter().enumerate() {
        check_frame(frame.as_slice().unwrap_or_default(), k, w, &name)?;
    }
    Ok((Frames::Whole(all, 0), (t, h, w)))
}

/// The first pixel of `frame` (frame `k`, `w` pixels a row) that is not finite and `>= 0`, as
/// the error that names it.
pub(crate) fn check_frame(
    frame: &[f32],
    k: usize,
    w: usize,
    name: &std::path::Display<'_>,
) -> eyre::Result<()> {
    if let Some((i, v)) = frame
        .iter()
        .enumerate()
        .find(|(_, v)| !(v.is_finite() && **v >= 0.0))
    {
        bail!(
            "{name}: frame {k} pixel ({}, {}) = {v}: intensities must be finite and >= 0",
            i % w,
            i / w
        );
    }
    Ok(())
}

/// Runs the DVS over the frames of `o.frames` and writes the events to `o.out`. A C-order file
/// is read a frame at a time (two frames of memory, whatever its length); a Fortran-order one
/// is read whole, and checked before any event is written.
///
/// # Errors
/// The frames cannot be read or are not float32 `[T, H, W]` with finite values `>= 0` (the
/// events of the frames before a bad one are written first); `dt_ns` is not positive; a DVS
/// setting is out of range; the output cannot be written.
pub fn run(o: &FramesToEventsOptions) -> eyre::Result<FramesToEventsSummary> {
    if o.dt_ns <= 0 {
        bail!("frames-to-events: --dt-ns = {} must be > 0", o.dt_ns);
    }
    if !(o.light_scale.is_finite() && o.light_scale > 0.0) {
        bail!(
            "frames-to-events: --light-scale = {} must be finite and > 0",
            o.light_scale
        );
    }
    let name = o.frames.display();
    let (mut frames, (t, h, w)) = open_frames(&o.frames)?;
    let cfg = frames_config(&o.dvs, w, h, "frames-to-events")?;
    let (mut prev, mut cur) = (Vec::with_capacity(h * w), Vec::with_capacity(h * w));
    frames.next_into(&mut prev, &name)?;
    check_frame(&prev, 0, w, &name)?;
    let mut steps = FrameSteps::new(&cfg, o.light_scale, &prev, o.dt_ns)
        .map_err(|e| eyre!("frames-to-events: {e}"))?;
    // The events go to `<out>.partial`, renamed to `out` once every frame is done: a run that
    // fails (a bad frame, a full disk, a kill) leaves its events there, never a shorter file
    // under the name that reads as whole.
    let partial = partial_path(&o.out);
    let file = std::fs::File::create(&partial)
        .wrap_err_with(|| format!("cannot create {}", partial.display()))?;
    let resolution = Resolution {
        width: w as u16,
        height: h as u16,
    };
    let mut writer = TextWriter::new(std::io::BufWriter::new(file), &partial, resolution, true)?;
    let mut summary = FramesToEventsSummary {
        frames: t,
        width: w,
        height: h,
        on: 0,
        off: 0,
        wall_s: 0.0,
    };
    for k in 1..t {
        // A bad frame ends the run after the events of the frames before it are written.
        if let Err(e) = frames
            .next_into(&mut cur, &name)
            .and_then(|()| check_frame(&cur, k, w, &name))
        {
            writer.finish()?;
            return Err(eyre!(
                "{e:#} (the events of the {k} frames before it are in {})",
                partial.display()
            ));
        }
        let start = Instant::now();
        let events = steps.next(&prev, &cur);
        summary.wall_s += start.elapsed().as_secs_f64();
        for e in events {
            if e.polarity > 0 {
                summary.on += 1;
            } else {
                summary.off += 1;
            }
            writer.write_event(e)?;
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    writer.finish()?;
    std::fs::rename(&partial, &o.out)
        .wrap_err_with(|| format!("cannot rename {} to {}", partial.display(), o.out.display()))?;
    Ok(summary)
}

/// `<out>.partial`: where the output is written until the run is done.
pub(crate) fn partial_path(out: &std::path::Path) -> std::path::PathBuf {
    let mut name = out.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    out.with_file_name(name)
}

/// Where the frames come from: the file a frame at a time, or an array read whole.
pub(crate) enum Frames {
    Stream(NpyFrames),
    Whole(Array3<f32>, usize),
}

impl Frames {
    /// The next frame into `frame`.
    pub(crate) fn next_into(
        &mut self,
        frame: &mut Vec<f32>,
        name: &std::path::Display<'_>,
    ) -> eyre::Result<()> {
        match self {
            Frames::Stream(r) => {
                if !r.read_frame(frame)? {
                    bail!("{name}: fewer frames than its header says");
                }
            }
            Frames::Whole(all, k) => {
                frame.clear();
                frame.extend(all.index_axis(Axis(0), *k).iter().copied());
                *k += 1;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn options(dir: &Path, frames: &Array3<f32>) -> FramesToEventsOptions {
        let path = dir.join("frames.npy");
        ndarray_npy::write_npy(&path, frames).expect("npy");
        FramesToEventsOptions {
            frames: path,
            dt_ns: 1_000_000,
            out: dir.join("events.txt"),
            light_scale: 1.0,
            dvs: DvsConfig {
                theta_sigma: 0.0,
                seed: 3,
                ..DvsConfig::default()
            },
        }
    }

    #[test]
    fn a_brightening_pixel_fires_as_many_on_events_as_its_log_change_holds() {
        let dir = tempfile::tempdir().expect("tempdir");
        // One pixel of 4 brightens from 0.1 to 0.1 e^1.0 over 5 frames: 1.0 / 0.2 = 5 ON events
        // (the last crossing lands at the end: 4 or 5, as the threshold's float sits); the
        // others stay still.
        let mut f = Array3::<f32>::from_elem((6, 2, 2), 0.5);
        for k in 0..6 {
            f[[k, 1, 0]] = 0.1 * (0.2 * k as f32 * 0.999).exp();
        }
        let o = options(dir.path(), &f);
        let s = run(&o).expect("run");
        assert_eq!((s.frames, s.width, s.height), (6, 2, 2));
        assert_eq!(s.off, 0);
        assert!((4..=5).contains(&s.on), "{s:?}");
        let text = std::fs::read_to_string(&o.out).expect("events");
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("2 2"));
        let rows: Vec<&str> = lines.collect();
        assert_eq!(rows.len() as u64, s.on);
        assert!(rows.iter().all(|r| r.ends_with(" 0 1 1")), "{rows:?}");
        assert!(s.json().contains(&format!("\"events\": {}", s.on)));
        // The same frames stored in Fortran order give the same events.
        let fortran = f.t().as_standard_layout().t().to_owned();
        assert!(!fortran.is_standard_layout());
        let o2 = options(dir.path(), &fortran);
        let s2 = run(&o2).expect("fortran");
        assert_eq!((s2.on, s2.off, s2.frames), (s.on, s.off, s.frames));
        assert_eq!(std::fs::read_to_string(&o2.out).expect("events"), text);
    }

    #[test]
    fn shot_noise_fires_on_still_frames_and_is_deterministic_for_a_seed() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = Array3::<f32>::from_elem((101, 20, 20), 0.2);
        let mut o = options(dir.path(), &f);
        assert_eq!(run(&o).expect("clean").on, 0);
        o.dvs.shot_noise_rate_hz = 5.0;
        let a = run(&o).expect("noisy");
        let b = run(&o).expect("again");
        assert_eq!(a.on + a.off, b.on + b.off);
        // 400 pixels x 0.1 s x 5 Hz x (1 - 0.75 x inten01(0.2)): 161 events on average (a
        // Poisson count: standard deviation 13), half of each polarity, as v2e's count.
        let n = a.on + a.off;
        assert!((110..=215).contains(&n), "{a:?}");
        assert!(a.on > 0 && a.off > 0);
    }

    #[test]
    fn bad_frames_and_settings_are_refused_by_name() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut f = Array3::<f32>::from_elem((3, 2, 2), 0.5);
        f.index_axis_mut(ndarray::Axis(0), 1).fill(1.0);
        f[[2, 1, 0]] = f32::NAN;
        let o = options(dir.path(), &f);
        let e = format!("{:#}", run(&o).expect_err("nan"));
        assert!(
            e.contains("frame 2 pixel (0, 1)") && e.contains("NaN"),
            "{e}"
        );
        // The events of the frames before the bad one are written, not lost, and not under the
        // name a whole run's file has.
        assert!(e.contains("events.txt.partial"), "{e}");
        assert!(!o.out.exists());
        let written = std::fs::read_to_string(partial_path(&o.out)).expect("events");
        assert!(
            written.lines().skip(1).any(|l| l.ends_with(" 1")),
            "{written}"
        );
        // Read whole (Fortran order), a bad frame is found before any event is written.
        let fortran = f.t().as_standard_layout().t().to_owned();
        let o = options(dir.path(), &fortran);
        let _ = std::fs::remove_file(&o.out);
        let e = run(&o).expect_err("nan").to_string();
        assert!(e.contains("frame 2 pixel (0, 1)"), "{e}");
        assert!(!o.out.exists());
        let one = options(dir.path(), &Array3::<f32>::zeros((1, 2, 2)));
        let e = run(&one).expect_err("one frame").to_string();
        assert!(e.contains("at least 2 frames"), "{e}");
        let zero_dt = FramesToEventsOptions {
            dt_ns: 0,
            ..one.clone()
        };
        assert!(
            run(&zero_dt)
                .expect_err("dt")
                .to_string()
                .contains("--dt-ns")
        );
        std::fs::write(&one.frames, b"\x93NUMPY garbage").expect("write");
        let e = run(&one).expect_err("garbage").to_string();
        assert!(
            e.contains("frames.npy") && e.contains("not a float32"),
            "{e}"
        );
        let mut o = options(dir.path(), &Array3::<f32>::zeros((2, 2, 2)));
        o.dvs.theta_on = -1.0;
        assert!(run(&o).expect_err("theta").to_string().contains("theta"));
        o.dvs.theta_on = 0.2;
        o.dvs.warp_step_ns = 1_000;
        let e = run(&o).expect_err("warp").to_string();
        assert!(e.contains("--warp-step-ns"), "{e}");
    }
}
