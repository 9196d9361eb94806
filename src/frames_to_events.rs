//! `neuspike frames-to-events`: the DVS pixel array run on a sequence of intensity frames, as
//! v2e runs its emulator on video frames, so that the two can be compared on the same input.
//!
//! Input: a `.npy` of float32 `[T, H, W]` intensities (the scene's luminance in `[0, 1]`), frame
//! `k` at `k * dt_ns`. The first frame sets every pixel's reference level; each later frame adds
//! the crossings of the log-intensity path from the frame before, and the noise of that
//! interval, exactly as [`DvsPixels::step`] does inside the event camera. Output: the events as
//! Event Camera Dataset text (`seconds x y polarity`, 1 ON / 0 OFF, a `width height` first
//! line), and a one-line JSON summary on stdout whose `wall_s` counts only the emulation (the
//! steps and the sorting of each step's events by time), not reading or writing.
//!
//! v2e's parameter names map onto these arguments one for one (docs/camera.md).

use std::path::{Path, PathBuf};
use std::time::Instant;

use eyre::{WrapErr, bail, eyre};
use ndarray::{ArrayView3, Axis};
use ndarray_npy::ViewNpyExt;
use neuspike_event_source::{DvsConfig, DvsPixels, sort_by_time};
use neuspike_formats::Resolution;
use neuspike_formats::text::TextWriter;
use neuspike_schemas::Event;

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

/// The DVS configuration of the options for frames of `width x height`: the rig and the
/// sampling (a scene's) are refused by name.
fn config(o: &FramesToEventsOptions, width: usize, height: usize) -> eyre::Result<DvsConfig> {
    let d = &o.dvs;
    let scene_only = [
        ("--homography", d.homography.is_some()),
        ("--clock-offset-ns", d.clock_offset_ns != 0),
        ("--warp-step-ns", d.warp_step_ns != 0),
    ];
    if let Some((name, _)) = scene_only.iter().find(|(_, set)| *set) {
        bail!("frames-to-events: {name} applies to a simulated scene, not to frames");
    }
    Ok(DvsConfig {
        width,
        height,
        ..d.clone()
    })
}

/// The frames of a `.npy` file's bytes, checked: float32, three axes, at least two frames, every
/// value finite and `>= 0`. The view borrows `bytes` (nothing is allocated from the header).
fn frames_of<'a>(bytes: &'a [u8], path: &Path) -> eyre::Result<ArrayView3<'a, f32>> {
    let name = path.display();
    let frames = ArrayView3::<f32>::view_npy(bytes)
        .map_err(|e| eyre!("{name}: not a float32 [T, H, W] .npy: {e}"))?;
    let (t, h, w) = frames.dim();
    if t < 2 || h == 0 || w == 0 || h > u16::MAX as usize || w > u16::MAX as usize {
        bail!("{name}: shape [{t}, {h}, {w}]: needs at least 2 frames of 1..=65535 pixels a side");
    }
    if let Some((i, v)) = frames
        .iter()
        .enumerate()
        .find(|(_, v)| !(v.is_finite() && **v >= 0.0))
    {
        let (k, rest) = (i / (h * w), i % (h * w));
        bail!(
            "{name}: frame {k} pixel ({}, {}) = {v}: intensities must be finite and >= 0",
            rest % w,
            rest / w
        );
    }
    Ok(frames)
}

/// Runs the DVS over the frames of `o.frames` and writes the events to `o.out`.
///
/// # Errors
/// The frames cannot be read or are not float32 `[T, H, W]` with finite values `>= 0`; `dt_ns`
/// is not positive; a DVS setting is out of range; the output cannot be written.
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
    // The bytes in 4-byte words, so that the float32 view is aligned.
    let bytes = std::fs::read(&o.frames).wrap_err_with(|| format!("{}", o.frames.display()))?;
    let n = bytes.len();
    let mut words = vec![0u32; n.div_ceil(4)];
    bytemuck::cast_slice_mut::<u32, u8>(&mut words)[..n].copy_from_slice(&bytes);
    drop(bytes);
    let frames = frames_of(&bytemuck::cast_slice::<u32, u8>(&words)[..n], &o.frames)?;
    let (t, h, w) = frames.dim();
    let cfg = config(o, w, h)?;
    // A C-order file's frames are read where they lie; another layout is copied once.
    let copy = (!frames.is_standard_layout()).then(|| frames.as_standard_layout().into_owned());
    let all = copy.as_ref().map_or(frames, |a| a.view());
    let frame = |k: usize| {
        all.index_axis_move(Axis(0), k)
            .to_slice()
            .unwrap_or_default()
    };
    let mut pixels = DvsPixels::new(&cfg, o.light_scale, frame(0))
        .map_err(|e| eyre!("frames-to-events: {e}"))?;
    let file = std::fs::File::create(&o.out)
        .wrap_err_with(|| format!("cannot create {}", o.out.display()))?;
    let resolution = Resolution {
        width: w as u16,
        height: h as u16,
    };
    let mut writer = TextWriter::new(std::io::BufWriter::new(file), &o.out, resolution, true)?;
    let mut summary = FramesToEventsSummary {
        frames: t,
        width: w,
        height: h,
        on: 0,
        off: 0,
        wall_s: 0.0,
    };
    let mut events: Vec<Event> = Vec::new();
    for k in 1..t {
        let t_a = (k as i64 - 1).saturating_mul(o.dt_ns);
        let t_b = (k as i64).saturating_mul(o.dt_ns);
        events.clear();
        let start = Instant::now();
        pixels.step(frame(k - 1), frame(k), t_a, t_b, &mut events);
        sort_by_time(&mut events);
        summary.wall_s += start.elapsed().as_secs_f64();
        for e in &events {
            if e.polarity > 0 {
                summary.on += 1;
            } else {
                summary.off += 1;
            }
            writer.write_event(e)?;
        }
    }
    writer.finish()?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;

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
        f[[2, 1, 0]] = f32::NAN;
        let o = options(dir.path(), &f);
        let e = run(&o).expect_err("nan").to_string();
        assert!(
            e.contains("frame 2 pixel (0, 1)") && e.contains("NaN"),
            "{e}"
        );
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
