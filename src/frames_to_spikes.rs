//! `neuspike frames-to-spikes`: the spike camera's pixels run on a sequence of intensity frames
//! (a video), as `frames-to-events` runs the DVS on them: the paper's integrate-and-fire model
//! without noise, on the camera's own kernel ([`neuspike_spike_camera::integrate_ticks`]).
//!
//! Input: a `.npy` of float32 `[T, H, W]` intensities (the scene's luminance in `[0, 1]`), frame
//! `k` at `k * dt_ns`, read a frame at a time (a Fortran-order file is read whole). Between two
//! frames the light is linear in time, as between the camera's key images
//! (`--render-step-ticks`); each tick adds `intensity x light_scale` to a pixel's accumulator,
//! which fires at `phi`. `dt_ns` must be a whole number of ticks: frame `k` is then tick
//! `k dt_ns / period`, and `(T - 1) dt_ns / period` planes are made. Every accumulator starts at
//! 0. Output: the planes as a PKU `.dat` (the Vidar camera's file: no header, rows bottom-up),
//! written to `<out>.partial` and renamed once whole; a one-line JSON summary on stdout.

use std::path::PathBuf;

use eyre::{WrapErr, bail, eyre};
use neuspike_formats::pku::{PkuGeometry, PkuWriter};
use neuspike_spike_camera::{KeyLight, PixelState, Reset, integrate_ticks};

use crate::frames_to_events::{check_frame, open_frames, partial_path};

/// The `neuspike frames-to-spikes` arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct FramesToSpikesOptions {
    /// Frames: a `.npy` of float32 `[T, H, W]` intensities in `[0, 1]`.
    #[arg(long)]
    pub frames: PathBuf,
    /// Time between two frames, nanoseconds: a whole number of the camera's ticks.
    #[arg(long)]
    pub dt_ns: i64,
    /// Output: the spike planes as a PKU `.dat`.
    #[arg(long)]
    pub out: PathBuf,
    /// Plane rate in Hz (the tick period is rounded to whole nanoseconds).
    #[arg(long, default_value_t = 20_000.0)]
    pub rate_hz: f64,
    /// Firing threshold phi, in units of intensity x light scale per tick.
    #[arg(long, default_value_t = 1.0)]
    pub phi: f32,
    /// The light scale the frames are seen at (intensity multiplier).
    #[arg(long, default_value_t = 1.0)]
    pub light_scale: f32,
    /// Accumulator reset after a spike.
    #[arg(long, value_enum, default_value_t = Reset::Subtract)]
    pub reset: Reset,
}

/// What a run made.
#[derive(Clone, Debug, PartialEq)]
pub struct FramesToSpikesSummary {
    /// Frames read.
    pub frames: usize,
    /// Sensor size.
    pub width: usize,
    /// Sensor size.
    pub height: usize,
    /// Planes written.
    pub planes: u64,
    /// Spikes in them.
    pub spikes: u64,
}

impl FramesToSpikesSummary {
    /// The summary as one JSON line, with the mean firing probability a pixel a plane (0 for
    /// no planes).
    pub fn json(&self) -> String {
        let cells = self.planes as f64 * (self.width * self.height) as f64;
        let rate = if cells > 0.0 {
            self.spikes as f64 / cells
        } else {
            0.0
        };
        format!(
            "{{\"frames\": {}, \"width\": {}, \"height\": {}, \"planes\": {}, \"spikes\": {}, \"firing_probability\": {rate:.6}}}",
            self.frames, self.width, self.height, self.planes, self.spikes
        )
    }
}

/// Runs the spike camera's pixels over the frames of `o.frames` and writes the planes to
/// `o.out`.
///
/// # Errors
/// A setting is out of range (`dt_ns` not a positive whole number of ticks, a rate, threshold
/// or light scale not finite and > 0); the frames cannot be read or are not float32 `[T, H, W]`
/// with finite values `>= 0` (the planes of the frames before a bad one are written first, in
/// `<out>.partial`); the output cannot be written.
pub fn run(o: &FramesToSpikesOptions) -> eyre::Result<FramesToSpikesSummary> {
    const COMMAND: &str = "frames-to-spikes";
    if !(o.rate_hz.is_finite() && o.rate_hz > 0.0) {
        bail!(
            "{COMMAND}: --rate-hz = {} must be finite and > 0",
            o.rate_hz
        );
    }
    // Whole nanoseconds, at least 1 (a rate above 1 GHz has no whole period).
    let period_ns = (1e9 / o.rate_hz).round().max(1.0) as i64;
    if o.dt_ns <= 0 || o.dt_ns % period_ns != 0 {
        bail!(
            "{COMMAND}: --dt-ns = {} must be a positive whole number of the camera's {period_ns}-ns ticks (--rate-hz {})",
            o.dt_ns,
            o.rate_hz
        );
    }
    let ticks = u32::try_from(o.dt_ns / period_ns)
        .map_err(|_| eyre!("{COMMAND}: --dt-ns = {}: over 2^32 ticks a frame", o.dt_ns))?;
    for (name, v) in [("--phi", o.phi), ("--light-scale", o.light_scale)] {
        if !(v.is_finite() && v > 0.0) {
            bail!("{COMMAND}: {name} = {v} must be finite and > 0");
        }
    }
    let name = o.frames.display();
    let (mut frames, (t, h, w)) = open_frames(&o.frames)?;
    let n = h * w;
    let per = n.div_ceil(8);
    // One frame's planes at a time: refuse what would not fit in memory rather than abort.
    let bytes = (ticks as usize)
        .checked_mul(per)
        .filter(|&b| b <= 1 << 30)
        .ok_or_else(|| {
            eyre!(
                "{COMMAND}: --dt-ns = {}: {ticks} planes of {w}x{h} a frame is over 1 GiB",
                o.dt_ns
            )
        })?;
    let partial = partial_path(&o.out);
    let file = std::fs::File::create(&partial)
        .wrap_err_with(|| format!("cannot create {}", partial.display()))?;
    let mut writer = PkuWriter::new(
        std::io::BufWriter::new(file),
        &partial,
        PkuGeometry::new(w, h),
    )?;
    let (mut prev, mut cur) = (Vec::with_capacity(n), Vec::with_capacity(n));
    frames.next_into(&mut prev, &name)?;
    check_frame(&prev, 0, w, &name)?;
    scale(&mut prev, o.light_scale);
    let (mut acc, mut since, cap) = (vec![0f32; n], vec![0u32; n], vec![u32::MAX; n]);
    let mut planes = vec![0u8; bytes];
    let mut summary = FramesToSpikesSummary {
        frames: t,
        width: w,
        height: h,
        planes: 0,
        spikes: 0,
    };
    for k in 1..t {
        // A bad frame ends the run after the planes of the frames before it are written.
        if let Err(e) = frames
            .next_into(&mut cur, &name)
            .and_then(|()| check_frame(&cur, k, w, &name))
        {
            writer.finish()?;
            return Err(eyre!(
                "{e:#} (the planes of the {k} frames before it are in {})",
                partial.display()
            ));
        }
        scale(&mut cur, o.light_scale);
        planes.fill(0);
        let keys = [&prev[..], &cur[..]];
        let light = KeyLight {
            keys: &keys,
            step: ticks,
        };
        let px = PixelState {
            acc: &mut acc,
            since: &mut since,
            cap: &cap,
        };
        integrate_ticks(light, 0, o.phi, o.reset, px, &mut planes);
        summary.spikes += planes
            .iter()
            .map(|b| u64::from(b.count_ones()))
            .sum::<u64>();
        summary.planes += u64::from(ticks);
        writer.write_planes(&planes)?;
        std::mem::swap(&mut prev, &mut cur);
    }
    writer.finish()?;
    std::fs::rename(&partial, &o.out)
        .wrap_err_with(|| format!("cannot rename {} to {}", partial.display(), o.out.display()))?;
    Ok(summary)
}

/// `frame` times `s`: the light a tick gives each pixel.
fn scale(frame: &mut [f32], s: f32) {
    for v in frame {
        *v *= s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;
    use neuspike_formats::pku::{PkuOptions, PkuReader};
    use std::path::Path;

    fn options(dir: &Path, frames: &Array3<f32>) -> FramesToSpikesOptions {
        let path = dir.join("frames.npy");
        ndarray_npy::write_npy(&path, frames).expect("npy");
        FramesToSpikesOptions {
            frames: path,
            dt_ns: 2_000_000,
            out: dir.join("spikes.dat"),
            rate_hz: 20_000.0,
            phi: 1.0,
            light_scale: 1.0,
            reset: Reset::Subtract,
        }
    }

    /// Every plane of the file, top-down, as each pixel's spike count.
    fn counts(path: &Path, (h, w): (usize, usize)) -> (usize, Vec<u32>) {
        let opts = PkuOptions {
            geometry: PkuGeometry::new(w, h),
            plane_period_ns: 50_000,
            t_first_ns: 0,
        };
        let mut r = PkuReader::open(path, &opts).expect("a PKU file");
        let (mut planes, mut count) = (0, vec![0u32; h * w]);
        while let Some(c) = r.next_chunk(64).expect("planes") {
            for plane in c.bits.chunks_exact((h * w).div_ceil(8)) {
                for (i, n) in count.iter_mut().enumerate() {
                    *n += u32::from(plane[i / 8] >> (i % 8) & 1);
                }
            }
            planes += c.n_planes;
        }
        (planes, count)
    }

    #[test]
    fn each_pixel_fires_as_often_as_its_light_over_the_threshold() {
        let dir = tempfile::tempdir().expect("tempdir");
        // 3 frames 2 ms apart at 20 kHz: 2 x 40 planes. A still pixel at 0.25 fires every 4th
        // tick: 20 spikes; one at 1.0 every tick; one dark, never; and one ramping from 0 to 1
        // over the first interval, then still at 1: sum over the first 40 ticks of t / 40 is
        // 19.5, so 19 spikes, then 40.
        let mut f = Array3::<f32>::zeros((3, 2, 3));
        f.slice_mut(ndarray::s![.., 0, 0]).fill(0.25);
        f.slice_mut(ndarray::s![.., 0, 1]).fill(1.0);
        f[[1, 1, 2]] = 1.0;
        f[[2, 1, 2]] = 1.0;
        let o = options(dir.path(), &f);
        let s = run(&o).expect("runs");
        assert_eq!((s.frames, s.width, s.height, s.planes), (3, 3, 2, 80));
        let (planes, count) = counts(&o.out, (2, 3));
        assert_eq!(planes, 80);
        assert_eq!(count, [20, 80, 0, 0, 0, 19 + 40], "{count:?}");
        assert_eq!(s.spikes, count.iter().map(|&c| u64::from(c)).sum::<u64>());
        assert!(s.json().contains("\"planes\": 80"), "{}", s.json());
        assert!(!partial_path(&o.out).exists());
        // The light scale and the threshold act together: twice the light, twice the
        // threshold, the same planes.
        let twice = FramesToSpikesOptions {
            light_scale: 2.0,
            phi: 2.0,
            out: dir.path().join("twice.dat"),
            ..o.clone()
        };
        run(&twice).expect("runs");
        assert_eq!(
            std::fs::read(&twice.out).expect("read"),
            std::fs::read(&o.out).expect("read")
        );
    }

    #[test]
    fn bad_frames_and_settings_are_refused_by_name() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut f = Array3::<f32>::from_elem((3, 2, 2), 0.5);
        let o = options(dir.path(), &f);
        for (bad, what) in [
            (
                FramesToSpikesOptions {
                    dt_ns: 60_000,
                    ..o.clone()
                },
                "--dt-ns = 60000",
            ),
            (
                FramesToSpikesOptions {
                    rate_hz: 0.0,
                    ..o.clone()
                },
                "--rate-hz = 0",
            ),
            (
                FramesToSpikesOptions {
                    phi: f32::NAN,
                    ..o.clone()
                },
                "--phi = NaN",
            ),
        ] {
            let e = run(&bad).expect_err(what).to_string();
            assert!(e.contains(what), "{e}");
        }
        // A negative intensity in the last frame: named, and the first interval's planes kept.
        f[[2, 1, 0]] = -1.0;
        let o = options(dir.path(), &f);
        let e = format!("{:#}", run(&o).expect_err("a negative intensity"));
        assert!(e.contains("frame 2 pixel (0, 1) = -1"), "{e}");
        let (planes, _) = counts(&partial_path(&o.out), (2, 2));
        assert_eq!(planes, 40);
        assert!(!o.out.exists());
    }
}
