//! Ground truth recorded beside a spike file, in one of two forms:
//! - a folder of luminance PNGs listed in `timestamps.txt` (`plane t_ns file` per line, `#`
//!   comments), as `neuspike simulate` writes it: each frame belongs to a plane;
//! - an AEDAT 4 file whose APS frames (a DAVIS's intensity frames) are the truth: each frame is
//!   placed at its own timestamp (DV: the middle of the exposure), on the spike clock.
//!
//! The list is read and checked when the folder is opened; each frame is read when its plane is
//! played, so memory holds one frame (the AEDAT 4 file is streamed packet by packet).

use std::fs::File;
use std::io::BufReader;
use std::ops::Range;
use std::path::{Path, PathBuf};

use ndarray::Array2;
use neuspike_formats::aedat4::{Aedat4Frames, ApsFrame};
use neuspike_formats::sniff::{Format, sniff};
use neuspike_formats::truth::{TruthError, TruthList};

/// Ground truth for a played recording: what `--truth` names.
pub enum Truth {
    /// PNGs listed by plane.
    Folder(TruthList),
    /// The APS frames of an AEDAT 4 file.
    Aps(Box<ApsTruth>),
}

impl Truth {
    /// A folder is read as a [`TruthList`]; a file must be AEDAT 4 (told by its content).
    pub fn open(path: &Path) -> Result<Self, String> {
        if path.is_dir() {
            return TruthList::open(path)
                .map(Truth::Folder)
                .map_err(|e| match &e {
                    TruthError::Read { source, .. } => format!("{e}: {source}"),
                    TruthError::Line { .. } | TruthError::TooLong { .. } => e.to_string(),
                });
        }
        match sniff(path).map_err(|e| e.to_string())? {
            Format::Aedat4 => ApsTruth::open(path).map(|a| Truth::Aps(Box::new(a))),
            other => Err(format!(
                "{}: ground truth must be a folder with timestamps.txt or an AEDAT 4 file with \
                 APS frames; this is {other}",
                path.display()
            )),
        }
    }

    /// The frames of planes `planes` (absolute plane numbers), as `(t_ns, luminance)` in time
    /// order: a folder's frames at their planes' times, APS frames at their own times when those
    /// fall within `[plane_time_ns(start), plane_time_ns(end))`. Frames must be `(height,
    /// width)`; an error names the file, the frame and the sizes.
    pub fn frames_in(
        &mut self,
        planes: Range<u64>,
        plane_time_ns: impl Fn(u64) -> i64,
        height: usize,
        width: usize,
    ) -> Result<Vec<(i64, Array2<f32>)>, String> {
        match self {
            Truth::Folder(f) => f
                .in_range(planes)
                .iter()
                .map(|(plane, path)| {
                    Ok((plane_time_ns(*plane), read_truth_png(path, height, width)?))
                })
                .collect(),
            Truth::Aps(a) => a.frames_between(
                plane_time_ns(planes.start)..plane_time_ns(planes.end),
                height,
                width,
            ),
        }
    }
}

/// The APS frames of an AEDAT 4 file, read in time order as the recording is played.
pub struct ApsTruth {
    path: PathBuf,
    frames: Aedat4Frames<BufReader<File>>,
    /// The next frame, read but not yet due.
    next: Option<ApsFrame>,
    /// Frames read so far (the index errors name).
    read: u64,
    /// Time of the last frame read.
    last_t_ns: Option<i64>,
    /// Frames before the first played plane, passed over.
    pub skipped_before: u64,
}

impl ApsTruth {
    /// Opens `path` (its header is read and checked).
    pub fn open(path: &Path) -> Result<Self, String> {
        let frames = Aedat4Frames::open(path).map_err(|e| e.to_string())?;
        Ok(ApsTruth {
            path: path.to_path_buf(),
            frames,
            next: None,
            read: 0,
            last_t_ns: None,
            skipped_before: 0,
        })
    }

    /// The frames whose time lies in `span`, as luminance; earlier frames are counted in
    /// [`ApsTruth::skipped_before`]. Frame times must increase (DV writes them so); a frame
    /// that does not is an error naming it, as is one whose size is not `(height, width)`.
    pub fn frames_between(
        &mut self,
        span: Range<i64>,
        height: usize,
        width: usize,
    ) -> Result<Vec<(i64, Array2<f32>)>, String> {
        let mut out = Vec::new();
        loop {
            let f = match self.next.take() {
                Some(f) => f,
                None => match self.frames.next() {
                    None => return Ok(out),
                    Some(r) => {
                        let f = r.map_err(|e| e.to_string())?;
                        let index = self.read;
                        self.read += 1;
                        let name = || format!("{}: APS frame {index}", self.path.display());
                        if let Some(last) = self.last_t_ns
                            && f.t_ns <= last
                        {
                            return Err(format!(
                                "{}: at {} ns, not after the frame before it at {last} ns",
                                name(),
                                f.t_ns
                            ));
                        }
                        self.last_t_ns = Some(f.t_ns);
                        if (usize::from(f.height), usize::from(f.width)) != (height, width) {
                            return Err(format!(
                                "{}: the frame is {}x{}, the spike planes {width}x{height}",
                                name(),
                                f.width,
                                f.height
                            ));
                        }
                        f
                    }
                },
            };
            if f.t_ns < span.start {
                self.skipped_before += 1;
                continue;
            }
            if f.t_ns >= span.end {
                self.next = Some(f);
                return Ok(out);
            }
            let data = Array2::from_shape_vec((height, width), f.luminance())
                .map_err(|e| format!("{}: {e}", self.path.display()))?;
            out.push((f.t_ns, data));
        }
    }
}

/// A ground-truth PNG as luminance in `[0, 1]` (8- or 16-bit grey, or colour taken as its
/// luma), checked against the sensor size `(height, width)`.
pub fn read_truth_png(path: &Path, height: usize, width: usize) -> Result<Array2<f32>, String> {
    let img = image::open(path)
        .map_err(|e| {
            format!(
                "{}: cannot read the ground-truth frame: {e}",
                path.display()
            )
        })?
        .to_luma16();
    let (w, h) = (img.width() as usize, img.height() as usize);
    if (h, w) != (height, width) {
        return Err(format!(
            "{}: the ground-truth frame is {w}x{h}, the spike planes {width}x{height}",
            path.display()
        ));
    }
    let data: Vec<f32> = img
        .into_raw()
        .into_iter()
        .map(|v| f32::from(v) / 65535.0)
        .collect();
    Array2::from_shape_vec((h, w), data).map_err(|e| format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_levels_and_size_are_checked() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("f.png");
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(3, 2, |x, _| {
            image::Luma([[0u16, 32768, 65535][x as usize]])
        });
        img.save(&p).expect("save");
        let f = read_truth_png(&p, 2, 3).expect("read");
        assert_eq!(f[[1, 0]], 0.0);
        assert_eq!(f[[0, 2]], 1.0);
        assert!((f[[0, 1]] - 0.5).abs() < 1e-4);
        let e = read_truth_png(&p, 3, 3).expect_err("wrong size");
        assert!(e.contains("3x2") && e.contains("3x3"), "{e}");
        let e = read_truth_png(&dir.path().join("none.png"), 2, 3).expect_err("missing");
        assert!(e.contains("none.png"), "{e}");
    }

    /// An AEDAT 4 file with one 3x2 grey frame at each of `times_us` (pixel value = its index),
    /// and one 4x2 frame after them when `odd_size`.
    fn aps_file(dir: &Path, times_us: &[i64], odd_size: bool) -> PathBuf {
        use neuspike_formats::Resolution;
        use neuspike_formats::aedat4::{Aedat4Writer, Compression, FrameFormat};
        let path = dir.join("aps.aedat4");
        let f = File::create(&path).expect("create");
        let mut w =
            Aedat4Writer::new(f, &path, Resolution::new(4, 2), Compression::Lz4).expect("writer");
        let mut frame = |t_us: i64, width: u16, v: u8| {
            w.write_frame(&ApsFrame {
                t_ns: t_us * 1000,
                exposure_begin_ns: 0,
                exposure_end_ns: 0,
                format: FrameFormat::Gray,
                width,
                height: 2,
                pixels: vec![v; usize::from(width) * 2],
            })
            .expect("frame");
        };
        for (i, &t) in times_us.iter().enumerate() {
            frame(t, 3, i as u8 * 51);
        }
        if odd_size {
            frame(times_us.last().copied().unwrap_or(0) + 1, 4, 0);
        }
        w.finish().expect("finish");
        path
    }

    #[test]
    fn aps_frames_are_sent_at_their_own_times_as_the_planes_pass() {
        let dir = tempfile::tempdir().expect("tempdir");
        // Planes every 50 us: plane k spans [50k, 50(k+1)) us.
        let path = aps_file(dir.path(), &[10, 120, 130, 420], false);
        let Truth::Aps(mut t) = Truth::open(&path).expect("open") else {
            panic!("an AEDAT 4 file is APS truth");
        };
        let time = |k: u64| k as i64 * 50_000;
        // Playback starts at plane 1: the frame at 10 us is passed over.
        let got = t.frames_between(time(1)..time(3), 2, 3).expect("frames");
        let times: Vec<i64> = got.iter().map(|f| f.0).collect();
        assert_eq!(times, [120_000, 130_000]);
        assert_eq!(t.skipped_before, 1);
        assert!((got[0].1[[1, 2]] - 51.0 / 255.0).abs() < 1e-6);
        assert!(
            t.frames_between(time(3)..time(8), 2, 3)
                .expect("none")
                .is_empty()
        );
        let last = t
            .frames_between(time(8)..time(9), 2, 3)
            .expect("frame at 420 us");
        assert_eq!(last.len(), 1);
        assert!((last[0].1[[0, 0]] - 153.0 / 255.0).abs() < 1e-6);
        assert!(
            t.frames_between(time(9)..time(99), 2, 3)
                .expect("end")
                .is_empty()
        );
    }

    #[test]
    fn aps_frames_of_another_size_out_of_order_or_no_aedat_are_named() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = aps_file(dir.path(), &[10], true);
        let Ok(Truth::Aps(mut t)) = Truth::open(&path) else {
            panic!("APS truth");
        };
        let e = t.frames_between(0..1_000_000, 2, 3).expect_err("4x2 frame");
        assert!(
            e.contains("aps.aedat4")
                && e.contains("APS frame 1")
                && e.contains("4x2")
                && e.contains("3x2"),
            "{e}"
        );
        let path = aps_file(dir.path(), &[10, 10], false);
        let Ok(Truth::Aps(mut t)) = Truth::open(&path) else {
            panic!("APS truth");
        };
        let e = t
            .frames_between(0..1_000_000, 2, 3)
            .expect_err("equal times");
        assert!(e.contains("APS frame 1") && e.contains("not after"), "{e}");
        let text = dir.path().join("events.txt");
        std::fs::write(&text, "0.1 1 1 1\n").expect("write");
        let e = Truth::open(&text).err().expect("text is no truth");
        assert!(e.contains("events.txt") && e.contains("AEDAT 4"), "{e}");
    }
}
