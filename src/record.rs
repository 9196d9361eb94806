//! Recordings on disk: `neuspike simulate` writes a paired spike + event recording of a scene
//! with its ground truth, in the formats real cameras use, so that everything downstream (the
//! file-playing sources, other tools) can be checked against data whose truth is known.
//!
//! A recording folder holds:
//! - `spikes.dat`: PKU spike planes (no header, rows bottom-up, LSB first), `width x height`;
//! - `events.txt`: Event Camera Dataset text (`W H` line, then `t_seconds x y polarity` with
//!   polarity 0/1), nanosecond times written exactly;
//! - `events.raw`: the same events as Prophesee RAW EVT 2.0 (microseconds, floored and counted);
//! - `events.aedat4`: the same events as AEDAT 4 (iniVation DV; LZ4, microseconds) and, when
//!   the two cameras have one size, the ground truth as its APS frames (16-bit grey, at the
//!   planes' times floored to whole microseconds), as a DAVIS records its intensity frames;
//! - `ground-truth/<plane:08>.png`: 16-bit luminance in `[0, 1]` at every `gt_every_planes`-th
//!   plane, listed with their times in `ground-truth/timestamps.txt` (`plane t_ns file`);
//! - `recording.yml`: what was simulated (scene, resolutions, rates, counts, calibration).

use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use eyre::WrapErr;
use neuspike_event_camera::{DvsConfig, EventCamera};
use neuspike_formats::aedat4::{Aedat4Writer, ApsFrame, Compression, FrameFormat};
use neuspike_formats::evt2::Evt2Writer;
use neuspike_formats::pku::{PkuGeometry, PkuWriter};
use neuspike_formats::text::TextWriter;
use neuspike_formats::truth::TruthListWriter;
use neuspike_formats::{EventWriter, Resolution, WriteSummary};
use neuspike_image::{BitDepth, grey_levels, write_frame_png};
use neuspike_scene::Scene;
use neuspike_spike_camera::{CameraConfig, SpikeCamera};

/// What to simulate.
#[derive(Clone, Debug)]
pub struct SimulateOptions {
    /// Built-in scene name or scene YAML path.
    pub scene: String,
    /// Output folder (created).
    pub out: PathBuf,
    /// Spike planes to simulate (default: the scene's duration).
    pub planes: Option<u64>,
    /// Ground truth at every plane whose index is a multiple of this (0 = none).
    pub gt_every_planes: u64,
    /// Planes simulated per step (and events per step: the same time span).
    pub chunk_planes: usize,
    /// Also simulate the event camera.
    pub events: bool,
    /// The spike camera.
    pub spike: CameraConfig,
    /// The event camera.
    pub dvs: DvsConfig,
    /// Show a progress bar.
    pub progress: bool,
}

/// What a simulation wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// The folder.
    pub out: PathBuf,
    /// Spike planes written.
    pub planes: u64,
    /// Spikes written.
    pub spikes: u64,
    /// Events written.
    pub events: u64,
    /// Ground-truth frames written.
    pub ground_truth: u64,
    /// Ground-truth frames also written as APS frames in `events.aedat4`.
    pub aps_frames: u64,
    /// Events whose time had to be floored to whole microseconds in `events.raw`.
    pub floored_in_raw: u64,
}

/// Simulates `opts.scene` with both cameras and writes the recording folder.
pub fn simulate(opts: &SimulateOptions) -> eyre::Result<Recording> {
    let scene = Scene::load(&opts.scene)
        .wrap_err_with(|| format!("simulate: cannot load the scene `{}`", opts.scene))?;
    let mut spike = SpikeCamera::new(scene.clone(), opts.spike.clone())?;
    let mut dvs = if opts.events {
        Some(EventCamera::new(scene.clone(), opts.dvs.clone(), 0)?)
    } else {
        None
    };
    let total = opts.planes.unwrap_or_else(|| spike.total_planes());
    let chunk = opts.chunk_planes.max(1) as u64;
    let out = &opts.out;
    let gt_dir = out.join("ground-truth");
    fs::create_dir_all(&gt_dir).wrap_err_with(|| format!("cannot create {}", gt_dir.display()))?;
    let create = |name: &str| -> eyre::Result<(BufWriter<File>, PathBuf)> {
        let path = out.join(name);
        let f =
            File::create(&path).wrap_err_with(|| format!("cannot create {}", path.display()))?;
        Ok((BufWriter::new(f), path))
    };

    let (w, path) = create("spikes.dat")?;
    let geometry = PkuGeometry::new(opts.spike.width, opts.spike.height);
    let mut spikes_out = PkuWriter::new(w, path, geometry)?;
    let dvs_res = Resolution::new(
        u16::try_from(opts.dvs.width).wrap_err("event camera width")?,
        u16::try_from(opts.dvs.height).wrap_err("event camera height")?,
    );
    let mut text_out = None;
    let mut raw_out = None;
    let mut aedat_out = None;
    if dvs.is_some() {
        let (w, path) = create("events.txt")?;
        text_out = Some(TextWriter::new(w, path, dvs_res, true)?);
        let (w, path) = create("events.raw")?;
        raw_out = Some(Evt2Writer::new(w, path, dvs_res)?);
        let (w, path) = create("events.aedat4")?;
        aedat_out = Some(Aedat4Writer::new(w, path, dvs_res, Compression::Lz4)?);
    }
    // A DAVIS's frames have the sensor's size: the truth goes in only when the sizes agree.
    let truth_as_aps = (opts.dvs.width, opts.dvs.height) == (opts.spike.width, opts.spike.height);
    let (stamps, stamps_path) = create("ground-truth/timestamps.txt")?;
    let mut stamps = TruthListWriter::new(stamps)
        .wrap_err_with(|| format!("cannot write {}", stamps_path.display()))?;

    let bar = opts.progress.then(|| {
        let bar = indicatif::ProgressBar::new(total);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {elapsed} [{bar:30}] {pos}/{len} planes ({per_sec}) {msg}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    });
    let mut rec = Recording {
        out: out.clone(),
        planes: 0,
        spikes: 0,
        events: 0,
        ground_truth: 0,
        aps_frames: 0,
        floored_in_raw: 0,
    };
    while spike.tick() < total {
        let first = spike.tick();
        let n = (total - first).min(chunk);
        let c = spike.next_chunk(n as usize, rec.planes / chunk);
        rec.spikes += c
            .bits
            .iter()
            .map(|b| u64::from(b.count_ones()))
            .sum::<u64>();
        spikes_out.write_chunk(&c)?;
        rec.planes += n;
        if let (Some(cam), Some(text), Some(raw), Some(aedat)) =
            (&mut dvs, &mut text_out, &mut raw_out, &mut aedat_out)
        {
            // Events of the same span of time as the planes: [t(first), t(first + n)).
            let batch = cam.advance_to(spike.plane_time_ns(first + n), 0);
            text.write_batch(&batch)?;
            raw.write_batch(&batch)?;
            aedat.write_batch(&batch)?;
            rec.events += batch.len() as u64;
        }
        if opts.gt_every_planes > 0 {
            let step = opts.gt_every_planes;
            let mut k = first.div_ceil(step) * step;
            while k < first + n {
                let name = format!("{k:08}.png");
                let frame = spike.ground_truth(k);
                write_frame_png(&gt_dir.join(&name), frame.view(), BitDepth::Sixteen)?;
                if let (Some(aedat), true) = (&mut aedat_out, truth_as_aps) {
                    let t_ns = spike.plane_time_ns(k);
                    let (height, width) = frame.dim();
                    aedat.write_frame(&ApsFrame {
                        t_ns,
                        exposure_begin_ns: t_ns,
                        exposure_end_ns: t_ns,
                        format: FrameFormat::Gray16,
                        width: u16::try_from(width).wrap_err("frame width")?,
                        height: u16::try_from(height).wrap_err("frame height")?,
                        pixels: grey_levels(frame.view(), BitDepth::Sixteen)
                            .iter()
                            .flat_map(|v| v.to_le_bytes())
                            .collect(),
                    })?;
                    rec.aps_frames += 1;
                }
                stamps
                    .entry(k, spike.plane_time_ns(k), &name)
                    .wrap_err_with(|| format!("cannot write {}", stamps_path.display()))?;
                rec.ground_truth += 1;
                k += step;
            }
        }
        if let Some(bar) = &bar {
            bar.set_position(rec.planes);
            bar.set_message(format!("{} events", rec.events));
        }
    }
    if let Some(bar) = bar {
        bar.finish();
    }
    let flush = |s: (BufWriter<File>, WriteSummary)| -> eyre::Result<WriteSummary> {
        let (mut w, summary) = s;
        w.flush().wrap_err("flushing a recording file")?;
        Ok(summary)
    };
    flush(spikes_out.finish()?)?;
    if let Some(t) = text_out {
        flush(t.finish()?)?;
    }
    if let Some(r) = raw_out {
        rec.floored_in_raw = flush(r.finish()?)?.floored_timestamps;
    }
    if let Some(a) = aedat_out {
        flush(a.finish()?)?;
    }
    stamps
        .finish()
        .wrap_err_with(|| format!("cannot write {}", stamps_path.display()))?;
    write_manifest(opts, &spike, &rec)?;
    Ok(rec)
}

/// `recording.yml`: what the folder holds and how it was made.
fn write_manifest(
    opts: &SimulateOptions,
    spike: &SpikeCamera,
    rec: &Recording,
) -> eyre::Result<()> {
    let manifest = format!(
        "# written by `neuspike simulate`\n\
         scene: {scene:?}\n\
         spikes:\n  file: spikes.dat\n  format: pku-dat\n  width: {sw}\n  height: {sh}\n  \
         plane_period_ns: {period}\n  planes: {planes}\n  spikes: {spikes}\n  \
         # luminance = firing rate per tick * lum_per_rate (phi / light_scale)\n  \
         lum_per_rate: {lpr}\n  seed: {sseed}\n\
         events:\n  files: [events.txt, events.raw, events.aedat4]\n  width: {ew}\n  height: {eh}\n  \
         count: {events}\n  floored_in_raw: {floored}\n  seed: {eseed}\n  \
         # the ground truth again, as APS frames in events.aedat4 (when the sizes agree)\n  \
         aps_frames: {aps}\n\
         ground_truth:\n  folder: ground-truth\n  every_planes: {gt_every}\n  frames: {gt}\n",
        scene = opts.scene,
        sw = opts.spike.width,
        sh = opts.spike.height,
        period = spike.period_ns(),
        planes = rec.planes,
        spikes = rec.spikes,
        lpr = spike.lum_per_rate(),
        sseed = opts.spike.seed,
        ew = opts.dvs.width,
        eh = opts.dvs.height,
        events = rec.events,
        floored = rec.floored_in_raw,
        aps = rec.aps_frames,
        eseed = opts.dvs.seed,
        gt_every = opts.gt_every_planes,
        gt = rec.ground_truth,
    );
    let path = opts.out.join("recording.yml");
    // Last, and whole: a recording without its manifest is one that did not finish.
    neuspike_formats::atomic::write(&path, manifest)
        .wrap_err_with(|| format!("cannot write {}", path.display()))
}

/// The summary `neuspike info` prints for a recording file.
pub fn describe(
    path: &Path,
    spikes: &neuspike_formats::pku::PkuOptions,
    events: &neuspike_formats::ReadOptions,
) -> eyre::Result<String> {
    let info = neuspike_formats::info(path, spikes, events)?;
    Ok(info.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use neuspike_formats::aedat4::Aedat4Frames;
    use neuspike_formats::pku::{PkuOptions, PkuReader};
    use neuspike_formats::{ReadOptions, open_events, read_all};

    fn small(out: &Path) -> SimulateOptions {
        SimulateOptions {
            scene: "bright-slow".into(),
            out: out.to_path_buf(),
            planes: Some(100),
            gt_every_planes: 40,
            chunk_planes: 30,
            events: true,
            spike: CameraConfig {
                width: 40,
                height: 25,
                ..Default::default()
            },
            dvs: DvsConfig {
                width: 34,
                height: 26,
                ..Default::default()
            },
            progress: false,
        }
    }

    #[test]
    fn simulate_writes_a_recording_the_readers_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let opts = small(dir.path());
        let rec = simulate(&opts).unwrap();
        assert_eq!((rec.planes, rec.ground_truth), (100, 3)); // planes 0, 40, 80
        assert!(rec.spikes > 0 && rec.events > 0, "{rec:?}");

        // The spike file reads back to the same planes the camera makes.
        let mut cam =
            SpikeCamera::new(Scene::load("bright-slow").unwrap(), opts.spike.clone()).unwrap();
        let want = cam.next_chunk(100, 0);
        let ropts = PkuOptions {
            geometry: PkuGeometry::new(40, 25),
            ..Default::default()
        };
        let mut r = PkuReader::open(dir.path().join("spikes.dat"), &ropts).unwrap();
        let got = r.next_chunk(100).unwrap().unwrap();
        assert_eq!(got.bits, want.bits);
        assert!(r.next_chunk(100).unwrap().is_none());

        // The event files hold the same events (RAW and AEDAT 4 at microsecond resolution).
        let text = read_all(
            &mut *open_events(dir.path().join("events.txt"), &ReadOptions::default()).unwrap(),
        )
        .unwrap();
        let raw = read_all(
            &mut *open_events(dir.path().join("events.raw"), &ReadOptions::default()).unwrap(),
        )
        .unwrap();
        assert_eq!(text.len() as u64, rec.events);
        let aedat = read_all(
            &mut *open_events(dir.path().join("events.aedat4"), &ReadOptions::default()).unwrap(),
        )
        .unwrap();
        for micro in [&raw, &aedat] {
            assert_eq!(micro.len(), text.len());
            for i in 0..text.len() {
                let (a, b) = (text.get(i), micro.get(i));
                assert_eq!((a.x, a.y, a.polarity), (b.x, b.y, b.polarity));
                assert_eq!(a.t_ns / 1000 * 1000, b.t_ns);
            }
        }
        let stamps = fs::read_to_string(dir.path().join("ground-truth/timestamps.txt")).unwrap();
        assert!(stamps.contains("40 2000000 00000040.png"), "{stamps}");
        assert!(dir.path().join("ground-truth/00000080.png").exists());
        let manifest = fs::read_to_string(dir.path().join("recording.yml")).unwrap();
        let y: serde_yaml::Value = serde_yaml::from_str(&manifest).unwrap();
        assert_eq!(y["spikes"]["planes"].as_u64(), Some(100));
        assert_eq!(y["events"]["count"].as_u64(), Some(rec.events));
        // The cameras differ in size: no APS frames.
        assert_eq!(y["events"]["aps_frames"].as_u64(), Some(0));
        let frames = Aedat4Frames::open(dir.path().join("events.aedat4")).unwrap();
        assert_eq!(frames.count(), 0);
    }

    #[test]
    fn cameras_of_one_size_get_the_truth_as_aps_frames_too() {
        let dir = tempfile::tempdir().unwrap();
        let mut opts = small(dir.path());
        (opts.dvs.width, opts.dvs.height) = (40, 25);
        let rec = simulate(&opts).unwrap();
        assert_eq!((rec.ground_truth, rec.aps_frames), (3, 3));
        let frames: Vec<_> = Aedat4Frames::open(dir.path().join("events.aedat4"))
            .unwrap()
            .map(Result::unwrap)
            .collect();
        for (f, plane) in frames.iter().zip([0u64, 40, 80]) {
            assert_eq!(f.t_ns, plane as i64 * 50_000);
            assert_eq!((f.width, f.height, f.format), (40, 25, FrameFormat::Gray16));
            let png = neuspike_image::read_frame_png(
                &dir.path().join(format!("ground-truth/{plane:08}.png")),
            )
            .unwrap();
            assert_eq!(f.luminance(), png.iter().copied().collect::<Vec<f32>>());
        }
    }

    #[test]
    fn an_unknown_scene_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let mut opts = small(dir.path());
        opts.scene = "no-such-scene".into();
        let e = format!("{:#}", simulate(&opts).unwrap_err());
        assert!(e.contains("no-such-scene"), "{e}");
    }
}
