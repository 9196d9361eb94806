//! `neuspike aps-check`: a DAVIS recording's own APS frames run through the DVS pixel array, and
//! the events they make set against the events the sensor recorded beside them.
//!
//! A DAVIS records intensity frames (APS) and events from the same pixels on one clock, so its
//! frames are an input whose events are known: the check emulates the events of every interval
//! between two frames ([`DvsPixels::step`], as `frames-to-events` does) and compares them with
//! the recorded events of the same interval and pixels, as far as the frame rate allows:
//!
//! - the counts, ON and OFF, and with `--fit-threshold` the contrast threshold that makes the
//!   emulated events as many as the recorded ones (bisection on `theta_on = theta_off`);
//! - how the counts follow each other over the frame intervals, and over the pixels (per pixel,
//!   averaged over 3x3 pixels: Pearson correlations);
//! - what cannot match, measured: recorded events whose change the frames do not show (an event
//!   says its pixel's log intensity moved a threshold its way since the pixel's previous event;
//!   counted where the frames, from the start of the interval of that previous event (the first
//!   frame for a pixel's first) to the end of the event's own, move it less than half a
//!   threshold that way: noise, or a change faster than the frames, such as a flicker, a motion
//!   that comes and goes between two frames, or the frames' own exposure blur), pixels the
//!   frames show saturated (the APS's full scale or 0, where its log intensity is unknown), and
//!   events outside the frames' span.
//!
//! A correlation over values that do not vary (a still recording) has no value and is reported
//! as such. A file whose tail cannot be read (a recording cut off mid-packet) is checked up to
//! there, and the report says where and why it stopped.

use std::io::Write;
use std::path::{Path, PathBuf};

use eyre::{WrapErr, bail, eyre};
use neuspike_event_camera::{DvsConfig, DvsPixels};
use neuspike_formats::aedat4::{Aedat4Frames, ApsFrame};
use neuspike_formats::{EventReader, ReadOptions, open_events};
use neuspike_schemas::{Event, EventBatch};

/// The `neuspike aps-check` arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct ApsCheckOptions {
    /// An AEDAT 4 recording of a DAVIS: APS frames and events of one size.
    pub file: PathBuf,
    /// Also fit the contrast threshold (`theta_on = theta_off`) that makes the emulated events
    /// as many as the recorded ones, and report the comparison at it.
    #[arg(long)]
    pub fit_threshold: bool,
    /// Also write the report (Markdown) to this file.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// The pixel array's settings (v2e's names in docs/camera.md); the frames give the size,
    /// and the rig and sampling settings do not apply.
    #[command(flatten)]
    pub dvs: DvsConfig,
}

/// ON and OFF events.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    /// ON events.
    pub on: u64,
    /// OFF events.
    pub off: u64,
}

impl Counts {
    /// ON and OFF together.
    pub fn total(&self) -> u64 {
        self.on + self.off
    }

    fn add(&mut self, polarity: i8) {
        if polarity > 0 {
            self.on += 1;
        } else {
            self.off += 1;
        }
    }
}

/// What the check found at one threshold.
#[derive(Clone, Debug, PartialEq)]
pub struct ApsComparison {
    /// The contrast thresholds the emulation ran at (ON, OFF).
    pub theta: (f64, f64),
    /// The recorded events within the frames' span.
    pub recorded: Counts,
    /// The events the frames make.
    pub emulated: Counts,
    /// Pearson correlation of the two counts over the frame intervals; `None` where either does
    /// not vary.
    pub interval_correlation: Option<f64>,
    /// Pearson correlation of the two counts over the pixels, each averaged over its 3x3
    /// neighbourhood; `None` where either does not vary.
    pub pixel_correlation: Option<f64>,
    /// Recorded events whose change the frames do not show (see the module's docs), as a
    /// fraction of the recorded events (0 without events).
    pub unexplained: f64,
}

/// What `aps-check` reports.
#[derive(Clone, Debug, PartialEq)]
pub struct ApsCheck {
    /// The file.
    pub file: PathBuf,
    /// Frames used.
    pub frames: usize,
    /// Sensor size.
    pub width: usize,
    /// Sensor size.
    pub height: usize,
    /// First and last frame time, ns.
    pub span_ns: (i64, i64),
    /// Mean exposure, ns (0 when the file does not say).
    pub exposure_ns: i64,
    /// Pixel-frames at the APS's full scale or at 0, as a fraction of all.
    pub saturated: f64,
    /// Recorded events before the first frame or after the last.
    pub outside: u64,
    /// Why the check stopped before the file's end (a truncated or damaged tail), if it did:
    /// what came before was checked.
    pub ended_early: Option<String>,
    /// At the thresholds given.
    pub given: ApsComparison,
    /// At the fitted threshold, with `--fit-threshold`.
    pub fitted: Option<ApsComparison>,
}

/// Bisection steps of the threshold fit (on `ln theta`, from 0.01 to 2: about 1e-6 relative).
const FIT_STEPS: usize = 24;

/// The frame's luminance, checked against the first frame's size.
fn luminance(f: &ApsFrame, k: usize, size: (usize, usize), file: &Path) -> eyre::Result<Vec<f32>> {
    let (w, h) = (usize::from(f.width), usize::from(f.height));
    if (w, h) != size {
        bail!(
            "{}: APS frame {k} is {w}x{h}, the frames before it {}x{}",
            file.display(),
            size.0,
            size.1
        );
    }
    Ok(f.luminance())
}

/// The frames of `file`, one after the other, with their times checked to increase.
struct FrameWalk {
    frames: Aedat4Frames<std::io::BufReader<std::fs::File>>,
    file: PathBuf,
    size: (usize, usize),
    k: usize,
    last_t: i64,
    /// Why the frames ended before the file did (a truncated or damaged tail).
    ended_early: Option<String>,
}

impl FrameWalk {
    /// Opens `file` and reads its first frame: the walk and that frame's luminance and time.
    fn open(file: &Path) -> eyre::Result<(FrameWalk, Vec<f32>, i64, i64)> {
        let mut frames = Aedat4Frames::open(file).map_err(|e| eyre!("{e}"))?;
        let first = frames
            .next()
            .transpose()
            .map_err(|e| eyre!("{e}"))?
            .ok_or_else(|| {
                eyre!(
                    "{}: no APS frames (a DAVIS records them beside its events; this file has events only)",
                    file.display()
                )
            })?;
        let size = (usize::from(first.width), usize::from(first.height));
        if size.0 == 0 || size.1 == 0 {
            bail!("{}: APS frame 0 is {}x{}", file.display(), size.0, size.1);
        }
        let exposure = first.exposure_end_ns - first.exposure_begin_ns;
        let lum = first.luminance();
        let walk = FrameWalk {
            frames,
            file: file.to_path_buf(),
            size,
            k: 0,
            last_t: first.t_ns,
            ended_early: None,
        };
        Ok((walk, lum, first.t_ns, exposure))
    }

    /// The next frame's luminance, time and exposure; `None` after the last, or where the
    /// file cannot be read further (a truncated or damaged tail: the frames before it are
    /// checked, and [`FrameWalk::ended_early`] says why).
    fn next(&mut self) -> eyre::Result<Option<(Vec<f32>, i64, i64)>> {
        if self.ended_early.is_some() {
            return Ok(None);
        }
        let f = match self.frames.next().transpose() {
            Ok(Some(f)) => f,
            Ok(None) => return Ok(None),
            Err(e) => {
                self.ended_early = Some(e.to_string());
                return Ok(None);
            }
        };
        self.k += 1;
        if f.t_ns <= self.last_t {
            bail!(
                "{}: APS frame {} at t = {} ns is not after the frame before it ({} ns)",
                self.file.display(),
                self.k,
                f.t_ns,
                self.last_t
            );
        }
        self.last_t = f.t_ns;
        let lum = luminance(&f, self.k, self.size, &self.file)?;
        Ok(Some((lum, f.t_ns, f.exposure_end_ns - f.exposure_begin_ns)))
    }
}

/// The recorded events in time order, taken interval by interval.
struct Recorded {
    reader: Box<dyn EventReader + Send>,
    batch: EventBatch,
    at: usize,
    done: bool,
    /// Why the events ended before the file did.
    ended_early: Option<String>,
}

impl Recorded {
    /// Calls `f` on every recorded event before `t_end_ns` not yet taken; a read error ends
    /// the events there ([`Recorded::ended_early`] says why).
    fn take_until(&mut self, t_end_ns: i64, mut f: impl FnMut(Event)) -> eyre::Result<()> {
        loop {
            while self.at < self.batch.len() {
                let e = self.batch.get(self.at);
                if e.t_ns >= t_end_ns {
                    return Ok(());
                }
                f(e);
                self.at += 1;
            }
            if self.done {
                return Ok(());
            }
            self.at = 0;
            match self.reader.next_chunk(1 << 16) {
                Ok(Some(b)) => self.batch = b,
                Ok(None) => {
                    self.batch = EventBatch::empty(0, 0, 0, 0, 0);
                    self.done = true;
                }
                Err(e) => {
                    self.batch = EventBatch::empty(0, 0, 0, 0, 0);
                    self.done = true;
                    self.ended_early = Some(e.to_string());
                }
            }
        }
    }
}

/// Pearson correlation of `a` and `b`; `None` where either does not vary.
fn pearson(a: &[f64], b: &[f64]) -> Option<f64> {
    let n = a.len().min(b.len()) as f64;
    if n < 2.0 {
        return None;
    }
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    (saa > 0.0 && sbb > 0.0).then(|| sab / (saa * sbb).sqrt())
}

/// `counts` (row-major, `w` columns) averaged over each pixel's 3x3 neighbourhood (fewer at the
/// border).
fn box3(counts: &[u32], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut n) = (0.0, 0.0);
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    s += f64::from(counts[yy * w + xx]);
                    n += 1.0;
                }
            }
            out[y * w + x] = s / n;
        }
    }
    out
}

/// The emulated events of the whole file at `theta`, and with `with_recorded` the comparison
/// with the recorded ones (else only the emulated counts are filled in).
fn compare(
    o: &ApsCheckOptions,
    theta: (f64, f64),
    with_recorded: bool,
) -> eyre::Result<(ApsComparison, FrameStats)> {
    let (mut walk, mut prev, t_first, exposure0) = FrameWalk::open(&o.file)?;
    let (w, h) = walk.size;
    let cfg = DvsConfig {
        theta_on: theta.0,
        theta_off: theta.1,
        ..crate::frames_to_events::frames_config(&o.dvs, w, h, "aps-check")?
    };
    let mut pixels = DvsPixels::new(&cfg, 1.0, &prev).map_err(|e| eyre!("aps-check: {e}"))?;
    let mut recorded = if with_recorded {
        let reader = open_events(&o.file, &ReadOptions::default()).map_err(|e| eyre!("{e}"))?;
        let r = reader.resolution();
        if (usize::from(r.width), usize::from(r.height)) != (w, h) {
            bail!(
                "{}: the events are {}x{}, the APS frames {w}x{h}: not one sensor",
                o.file.display(),
                r.width,
                r.height
            );
        }
        Some(Recorded {
            reader,
            batch: EventBatch::empty(w, h, 0, 0, 0),
            at: 0,
            done: false,
            ended_early: None,
        })
    } else {
        None
    };
    let mut stats = FrameStats {
        frames: 1,
        size: (w, h),
        span_ns: (t_first, t_first),
        exposure_sum_ns: exposure0,
        saturated: saturated(&prev),
        outside: 0,
        ended_early: None,
    };
    if let Some(r) = &mut recorded {
        r.take_until(t_first, |_| stats.outside += 1)?;
    }
    let (mut rec_total, mut emu_total) = (Counts::default(), Counts::default());
    let (mut rec_px, mut emu_px) = (vec![0u32; w * h], vec![0u32; w * h]);
    let (mut rec_iv, mut emu_iv) = (Vec::new(), Vec::new());
    // Each pixel's log intensity at the start of the interval of its latest recorded event
    // (the first frame's before its first): what its next event's change is measured from.
    let floor = cfg.log_floor as f32;
    let log = |v: f32| v.max(floor).ln();
    let mut reference: Vec<f32> = prev.iter().map(|&v| log(v)).collect();
    let half = (0.5 * theta.0 as f32, 0.5 * theta.1 as f32);
    let mut unexplained = 0u64;
    let mut events = Vec::new();
    let mut t_a = t_first;
    while let Some((cur, t_b, exposure)) = walk.next()? {
        stats.frames += 1;
        stats.span_ns.1 = t_b;
        stats.exposure_sum_ns += exposure;
        stats.saturated += saturated(&cur);
        events.clear();
        pixels.step(&prev, &cur, t_a, t_b, &mut events);
        for e in &events {
            emu_total.add(e.polarity);
            emu_px[usize::from(e.y) * w + usize::from(e.x)] += 1;
        }
        emu_iv.push(events.len() as f64);
        if let Some(r) = &mut recorded {
            let mut n = 0u64;
            r.take_until(t_b, |e| {
                let i = usize::from(e.y) * w + usize::from(e.x);
                rec_total.add(e.polarity);
                rec_px[i] += 1;
                n += 1;
                let change = log(cur[i]) - reference[i];
                let shown = if e.polarity > 0 {
                    change >= half.0
                } else {
                    -change >= half.1
                };
                if !shown {
                    unexplained += 1;
                }
                reference[i] = log(prev[i]);
            })?;
            rec_iv.push(n as f64);
        }
        prev = cur;
        t_a = t_b;
    }
    if stats.frames < 2 {
        match &walk.ended_early {
            Some(why) => bail!("one APS frame could be read, the check needs two or more: {why}"),
            None => bail!(
                "{}: one APS frame: the check needs two or more",
                o.file.display()
            ),
        }
    }
    stats.ended_early = walk.ended_early.take();
    if let Some(r) = &mut recorded {
        r.take_until(i64::MAX, |_| stats.outside += 1)?;
        stats.ended_early = stats.ended_early.take().or(r.ended_early.take());
    }
    let comparison = ApsComparison {
        theta,
        recorded: rec_total,
        emulated: emu_total,
        interval_correlation: with_recorded.then(|| pearson(&rec_iv, &emu_iv)).flatten(),
        pixel_correlation: with_recorded
            .then(|| pearson(&box3(&rec_px, w, h), &box3(&emu_px, w, h)))
            .flatten(),
        unexplained: if rec_total.total() > 0 {
            unexplained as f64 / rec_total.total() as f64
        } else {
            0.0
        },
    };
    Ok((comparison, stats))
}

/// What the frames themselves say.
struct FrameStats {
    frames: usize,
    size: (usize, usize),
    span_ns: (i64, i64),
    exposure_sum_ns: i64,
    /// Saturated pixel-frames so far.
    saturated: u64,
    outside: u64,
    /// Why the frames or the events ended before the file did.
    ended_early: Option<String>,
}

/// Pixels of a frame at 0 or at full scale.
fn saturated(lum: &[f32]) -> u64 {
    lum.iter().filter(|&&v| v <= 0.0 || v >= 1.0).count() as u64
}

/// Runs the check.
///
/// # Errors
/// The file cannot be read, has no APS frames or only one, frames of two sizes or out of time
/// order, or events of another size; a DVS setting is out of range.
pub fn run(o: &ApsCheckOptions) -> eyre::Result<ApsCheck> {
    let given_theta = (o.dvs.theta_on, o.dvs.theta_off);
    let (given, stats) = compare(o, given_theta, true)?;
    let fitted = if o.fit_threshold {
        let target = given.recorded.total();
        if target == 0 {
            bail!(
                "{}: no recorded events within the frames' span: no threshold to fit",
                o.file.display()
            );
        }
        // More events at a lower threshold: bisect ln(theta) for the emulated count to reach
        // the recorded one.
        let (mut lo, mut hi) = (0.01f64.ln(), 2.0f64.ln());
        for _ in 0..FIT_STEPS {
            let mid = 0.5 * (lo + hi);
            let theta = mid.exp();
            let (c, _) = compare(o, (theta, theta), false)?;
            if c.emulated.total() > target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let theta = (0.5 * (lo + hi)).exp();
        Some(compare(o, (theta, theta), true)?.0)
    } else {
        None
    };
    let (w, h) = stats.size;
    let pixel_frames = (stats.frames * w * h) as f64;
    Ok(ApsCheck {
        file: o.file.clone(),
        frames: stats.frames,
        width: w,
        height: h,
        span_ns: stats.span_ns,
        exposure_ns: stats.exposure_sum_ns / stats.frames as i64,
        saturated: stats.saturated as f64 / pixel_frames,
        outside: stats.outside,
        ended_early: stats.ended_early,
        given,
        fitted,
    })
}

impl ApsCheck {
    /// The report, as Markdown.
    pub fn markdown(&self) -> String {
        let span_s = (self.span_ns.1 - self.span_ns.0) as f64 * 1e-9;
        let rate = |c: &Counts| c.total() as f64 / span_s;
        let r = |v: Option<f64>| {
            v.map_or_else(|| "no value (no variation)".into(), |v| format!("{v:.3}"))
        };
        let exposure = if self.exposure_ns > 0 {
            format!(
                "exposure {:.2} ms on average",
                self.exposure_ns as f64 * 1e-6
            )
        } else {
            "exposure not stated".into()
        };
        let mut s = format!(
            "# APS check: {}\n\n{} APS frames of {}x{} over {:.3} s ({:.1} frames/s), {exposure}.\n\n",
            self.file.display(),
            self.frames,
            self.width,
            self.height,
            span_s,
            (self.frames - 1) as f64 / span_s,
        );
        let mut table = |c: &ApsComparison, title: &str| {
            s += &format!(
                "## {title} (theta ON {:.4}, OFF {:.4})\n\n\
                 | | recorded | emulated from the APS frames |\n|---|---|---|\n\
                 | ON events | {} | {} |\n| OFF events | {} | {} |\n\
                 | events/s | {:.0} | {:.0} ({:.2}x) |\n\
                 | per frame interval, correlation | {} | |\n\
                 | per pixel (3x3 mean), correlation | {} | |\n\n\
                 Recorded events whose change the frames do not show (less than half a threshold \
                 their way since the pixel's previous event): {:.1}% (noise, or a change faster \
                 than the frames).\n\n",
                c.theta.0,
                c.theta.1,
                c.recorded.on,
                c.emulated.on,
                c.recorded.off,
                c.emulated.off,
                rate(&c.recorded),
                rate(&c.emulated),
                c.emulated.total() as f64 / c.recorded.total().max(1) as f64,
                r(c.interval_correlation),
                r(c.pixel_correlation),
                100.0 * c.unexplained,
            );
        };
        table(&self.given, "At the thresholds given");
        if let Some(f) = &self.fitted {
            table(f, "At the fitted threshold");
        }
        s += &format!(
            "What the frames cannot show: {:.2}% of the pixel-frames are saturated (0 or full \
             scale); {} recorded events lie outside the frames' span.\n",
            100.0 * self.saturated,
            self.outside
        );
        if let Some(why) = &self.ended_early {
            s += &format!(
                "\nThe file could not be read to its end ({why}): the check covers what came before.\n"
            );
        }
        s
    }
}

/// Runs the check and prints (and with `--report` writes) the report.
///
/// # Errors
/// As [`run`], or the report cannot be written.
pub fn main(o: &ApsCheckOptions) -> eyre::Result<()> {
    let check = run(o)?;
    let text = check.markdown();
    if let Some(path) = &o.report {
        neuspike_formats::atomic::write(path, &text)
            .wrap_err_with(|| format!("cannot write {}", path.display()))?;
    }
    std::io::stdout()
        .write_all(text.as_bytes())
        .wrap_err("cannot write the report")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::{SimulateOptions, simulate};
    use neuspike_spike_camera::CameraConfig;

    /// A simulated recording of `bright-slow`: the spike camera `spike` in size, the DVS as
    /// `dvs` says, the truth every `every` planes (20 kHz), as APS frames where the sizes agree.
    fn recording(
        dir: &Path,
        planes: u64,
        every: u64,
        spike: (usize, usize),
        dvs: DvsConfig,
    ) -> PathBuf {
        simulate(&SimulateOptions {
            scene: "bright-slow".into(),
            out: dir.to_path_buf(),
            planes: Some(planes),
            gt_every_planes: every,
            chunk_planes: 100,
            events: true,
            spike: CameraConfig {
                width: spike.0,
                height: spike.1,
                ..Default::default()
            },
            dvs,
            progress: false,
        })
        .expect("simulate");
        dir.join("events.aedat4")
    }

    /// A simulated DAVIS: both cameras 80x50, the events with `dvs`'s settings.
    fn davis(dir: &Path, planes: u64, every: u64, dvs: DvsConfig) -> PathBuf {
        let dvs = DvsConfig {
            width: 80,
            height: 50,
            ..dvs
        };
        recording(dir, planes, every, (80, 50), dvs)
    }

    fn options(file: PathBuf) -> ApsCheckOptions {
        ApsCheckOptions {
            file,
            fit_threshold: false,
            report: None,
            dvs: DvsConfig::default(),
        }
    }

    #[test]
    fn a_recording_whose_frames_made_its_events_passes_and_its_threshold_is_found() {
        let dir = tempfile::tempdir().expect("tempdir");
        // Frames at 1 kHz; events from the scene itself, threshold 0.25.
        let dvs = DvsConfig {
            theta_on: 0.25,
            theta_off: 0.25,
            ..DvsConfig::default()
        };
        let file = davis(dir.path(), 2000, 20, dvs);
        let mut o = options(file);
        o.fit_threshold = true;
        let c = run(&o).expect("check");
        assert_eq!((c.frames, c.width, c.height), (100, 80, 50));
        assert_eq!(c.span_ns, (0, 99 * 20 * 50_000));
        // At the default threshold (0.2) the frames make more events than were recorded.
        let g = &c.given;
        let ratio = g.emulated.total() as f64 / g.recorded.total() as f64;
        assert!(ratio > 1.2, "{c:?}");
        let f = c.fitted.as_ref().expect("fitted");
        assert!((f.theta.0 - 0.25).abs() < 0.01, "{f:?}");
        let ratio = f.emulated.total() as f64 / f.recorded.total() as f64;
        assert!((ratio - 1.0).abs() < 0.01, "{f:?}");
        assert!(f.interval_correlation.expect("varies") > 0.9, "{f:?}");
        assert!(f.pixel_correlation.expect("varies") > 0.95, "{f:?}");
        assert!(f.unexplained < 0.02, "{f:?}");
        let md = c.markdown();
        assert!(md.contains("100 APS frames of 80x50"), "{md}");
        assert!(md.contains("At the fitted threshold (theta ON 0.2"), "{md}");
        // The command writes the same report.
        o.report = Some(dir.path().join("report.md"));
        main(&o).expect("main");
        let written = std::fs::read_to_string(dir.path().join("report.md")).expect("report");
        assert_eq!(written, md);
    }

    #[test]
    fn noise_the_frames_cannot_show_is_counted_as_unexplained() {
        let dir = tempfile::tempdir().expect("tempdir");
        let quiet = run(&options(davis(
            &dir.path().join("quiet"),
            1000,
            20,
            DvsConfig::default(),
        )))
        .expect("check");
        let noisy = run(&options(davis(
            &dir.path().join("noisy"),
            1000,
            20,
            DvsConfig {
                shot_noise_rate_hz: 20.0,
                ..DvsConfig::default()
            },
        )))
        .expect("check");
        assert!(quiet.given.unexplained < 0.02, "{quiet:?}");
        assert!(
            noisy.given.unexplained > quiet.given.unexplained + 0.05,
            "{:?} vs {:?}",
            noisy.given,
            quiet.given
        );
    }

    #[test]
    fn files_the_check_cannot_use_are_named_with_why() {
        let dir = tempfile::tempdir().expect("tempdir");
        // Cameras of two sizes: no APS frames.
        let dvs = DvsConfig {
            width: 34,
            height: 26,
            ..DvsConfig::default()
        };
        let file = recording(&dir.path().join("two-sizes"), 100, 20, (40, 25), dvs);
        let e = run(&options(file.clone()))
            .expect_err("no frames")
            .to_string();
        assert!(
            e.contains(&file.display().to_string()) && e.contains("no APS frames"),
            "{e}"
        );
        // One frame.
        let file = davis(&dir.path().join("one"), 100, 1000, DvsConfig::default());
        let e = run(&options(file)).expect_err("one frame").to_string();
        assert!(e.contains("one APS frame"), "{e}");
        // A rig setting.
        let file = davis(&dir.path().join("rig"), 100, 20, DvsConfig::default());
        let mut o = options(file);
        o.dvs.clock_offset_ns = 5;
        let e = run(&o).expect_err("rig").to_string();
        assert!(e.contains("--clock-offset-ns"), "{e}");
        // A tail cut off mid-packet: what came before is checked, and the report says so.
        let file = davis(&dir.path().join("cut"), 2000, 20, DvsConfig::default());
        let whole = run(&options(file.clone())).expect("whole");
        assert_eq!(whole.ended_early, None);
        let bytes = std::fs::read(&file).expect("file");
        let cut = dir.path().join("cut.aedat4");
        std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).expect("write");
        let part = run(&options(cut)).expect("the part before the cut");
        assert!(part.frames >= 2 && part.frames < whole.frames, "{part:?}");
        let why = part.ended_early.as_deref().expect("why it stopped");
        assert!(why.contains("truncated"), "{why}");
        assert!(part.markdown().contains("could not be read to its end"));
        // Not a file at all.
        let e = run(&options(dir.path().join("missing.aedat4")))
            .expect_err("missing")
            .to_string();
        assert!(e.contains("missing.aedat4"), "{e}");
    }

    #[test]
    fn pearson_has_no_value_without_variation() {
        assert_eq!(pearson(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]), None);
        assert_eq!(pearson(&[1.0], &[1.0]), None);
        let r = pearson(&[1.0, 2.0, 3.0], &[2.0, 4.0, 6.5]).expect("varies");
        assert!(r > 0.99 && r <= 1.0, "{r}");
        let b = box3(&[0, 0, 0, 0, 9, 0, 0, 0, 0], 3, 3);
        assert_eq!(b[4], 1.0);
        assert_eq!(b[0], 9.0 / 4.0);
    }
}
