//! Frames as images: grey PNG at 8 or 16 bits, written atomically, and read back to `[0, 1]`;
//! the grey levels a frame has at a bit depth, for other containers of the same frames (AEDAT 4's
//! APS frames, ROS 2 `sensor_msgs/Image`).
//!
//! ```
//! use ndarray::Array2;
//! use neuspike_image::{BitDepth, grey_levels};
//!
//! let frame = Array2::from_shape_vec((1, 3), vec![0.0f32, 0.5, 2.0]).expect("shape");
//! // round(clamp(v, 0, 1) * 255), half away from zero
//! assert_eq!(grey_levels(frame.view(), BitDepth::Eight), vec![0, 128, 255]);
//! ```
#![deny(missing_docs)]

use std::fs::{self, File};
use std::io::{BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use image::codecs::png::{PngDecoder, PngEncoder};
use image::{DynamicImage, ExtendedColorType, ImageEncoder};
use ndarray::{Array2, ArrayView2};

/// What can go wrong while a frame is written as an image or read back. Every message names the
/// file; the cause is the error's source (printed after it in a chain, never twice).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Creating, writing, renaming or opening a file failed.
    #[error("I/O error on {}", path.display())]
    Io {
        /// The file the operation was on (for an atomic write, the `.tmp` file or the target).
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// Encoding or decoding a PNG failed.
    #[error("PNG error on {}", path.display())]
    Png {
        /// The file being encoded or decoded.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: image::ImageError,
    },
    /// A frame that a PNG cannot hold: zero rows or columns, or a side above `u32::MAX`.
    #[error("cannot write {}: frame of {rows}x{cols} pixels has no PNG form", path.display())]
    BadShape {
        /// The file that was to be written.
        path: PathBuf,
        /// Rows of the frame.
        rows: usize,
        /// Columns of the frame.
        cols: usize,
    },
    /// A PNG that is not single-channel grey (8 or 16 bit).
    #[error("{} is not a grey PNG (colour type {color})", path.display())]
    NotGrey {
        /// The file read.
        path: PathBuf,
        /// The colour type found, as `image` names it.
        color: String,
    },
}

/// Bits per grey sample of a written PNG.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BitDepth {
    /// 8 bits: levels 0..=255.
    Eight,
    /// 16 bits: levels 0..=65535.
    Sixteen,
}

impl BitDepth {
    /// The largest grey level: 255 or 65535.
    pub fn max_level(self) -> u16 {
        match self {
            BitDepth::Eight => u16::from(u8::MAX),
            BitDepth::Sixteen => u16::MAX,
        }
    }
}

impl std::fmt::Display for BitDepth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BitDepth::Eight => "8",
            BitDepth::Sixteen => "16",
        })
    }
}

/// A bit depth that is neither `8` nor `16`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("bit depth must be \"8\" or \"16\", got {value:?}")]
pub struct ParseBitDepthError {
    /// The text that was given.
    pub value: String,
}

impl std::str::FromStr for BitDepth {
    type Err = ParseBitDepthError;

    /// Parses exactly `"8"` or `"16"`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "8" => Ok(BitDepth::Eight),
            "16" => Ok(BitDepth::Sixteen),
            other => Err(ParseBitDepthError {
                value: other.to_owned(),
            }),
        }
    }
}

/// `path` with `.tmp` appended to its file name: `frame.png` -> `frame.png.tmp`, same folder.
pub fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".tmp");
    PathBuf::from(name)
}

/// Grey level of a luminance: `round(clamp(v, 0, 1) * max)`, half away from zero, in f64; NaN -> 0.
/// (`floor(y + 0.5)` is that rounding for `y >= 0`, exact in f64 here; `NaN as u16` is 0.)
#[inline(always)]
fn level(v: f32, max: u16) -> u16 {
    (f64::from(v).clamp(0.0, 1.0) * f64::from(max) + 0.5) as u16
}

/// The grey levels of `frame` in row-major order, vectorised when the frame is contiguous.
fn levels<T>(frame: ArrayView2<f32>, max: u16, cast: impl Fn(u16) -> T + Copy) -> Vec<T> {
    match frame.as_slice() {
        Some(xs) => neuspike_simd::dispatch(
            #[inline(always)]
            || xs.iter().map(|&v| cast(level(v, max))).collect(),
        ),
        None => frame.iter().map(|&v| cast(level(v, max))).collect(),
    }
}

/// The grey levels of `frame` at `depth`, row-major, as [`write_frame_png`] writes them (for other
/// containers of the same frames, such as AEDAT 4's APS frames).
pub fn grey_levels(frame: ArrayView2<f32>, depth: BitDepth) -> Vec<u16> {
    levels(frame, depth.max_level(), |v| v)
}

/// Writes `contents` to `path` through `<path>.tmp` and a rename, so that a reader never sees a
/// half-written file. On failure the `.tmp` file is removed (best effort) and `path` is untouched.
///
/// `contents` writes into the buffered `.tmp` file (its path is the second argument, for errors);
/// an I/O error of the file itself is an [`Error::Io`], turned into the caller's error type.
pub fn write_atomically<E: From<Error>>(
    path: &Path,
    contents: impl FnOnce(&mut BufWriter<File>, &Path) -> Result<(), E>,
) -> Result<(), E> {
    let tmp = tmp_path(path);
    let result = (|| {
        let file = File::create(&tmp).map_err(|source| {
            E::from(Error::Io {
                path: tmp.clone(),
                source,
            })
        })?;
        let mut out = BufWriter::new(file);
        contents(&mut out, &tmp)?;
        out.flush().map_err(|source| {
            E::from(Error::Io {
                path: tmp.clone(),
                source,
            })
        })?;
        drop(out);
        fs::rename(&tmp, path).map_err(|source| {
            E::from(Error::Io {
                path: path.to_owned(),
                source,
            })
        })
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Writes `frame` (rows x cols, luminance) as a grey PNG of `depth` bits at `path`.
///
/// Values are clamped to `[0, 1]` (NaN is written as 0), scaled to 255 or 65535 and rounded half
/// away from zero. The write is atomic: the PNG goes to `<path>.tmp` in the same folder, which is
/// then renamed over `path` (no fsync: this guards readers, not power loss). A frame with no
/// pixels, or a side above `u32::MAX`, is a [`Error::BadShape`]; a missing folder is a
/// [`Error::Io`] naming the `.tmp` file.
pub fn write_frame_png(path: &Path, frame: ArrayView2<f32>, depth: BitDepth) -> Result<(), Error> {
    let (rows, cols) = frame.dim();
    let bad_shape = || Error::BadShape {
        path: path.to_owned(),
        rows,
        cols,
    };
    if rows == 0 || cols == 0 {
        return Err(bad_shape());
    }
    let width = u32::try_from(cols).map_err(|_| bad_shape())?;
    let height = u32::try_from(rows).map_err(|_| bad_shape())?;
    let max = depth.max_level();
    write_atomically(path, |out, tmp| {
        let png_error = |source| Error::Png {
            path: tmp.to_owned(),
            source,
        };
        let encoder = PngEncoder::new(out);
        match depth {
            BitDepth::Eight => {
                // level() is at most max_level() = 255 here
                let data = levels(frame, max, |l| l as u8);
                encoder.write_image(&data, width, height, ExtendedColorType::L8)
            }
            BitDepth::Sixteen => {
                let data = levels(frame, max, |l| l);
                let bytes: Vec<u8> = data.iter().flat_map(|l| l.to_ne_bytes()).collect();
                encoder.write_image(&bytes, width, height, ExtendedColorType::L16)
            }
        }
        .map_err(png_error)
    })
}

/// Reads a grey PNG (8 or 16 bit) back to luminance in `[0, 1]`: level / 255 or level / 65535.
///
/// Other colour types are a [`Error::NotGrey`]; used by tests and tools.
pub fn read_frame_png(path: &Path) -> Result<Array2<f32>, Error> {
    let file = File::open(path).map_err(|source| Error::Io {
        path: path.to_owned(),
        source,
    })?;
    let png_error = |source| Error::Png {
        path: path.to_owned(),
        source,
    };
    let decoder = PngDecoder::new(BufReader::new(file)).map_err(png_error)?;
    let img = DynamicImage::from_decoder(decoder).map_err(png_error)?;
    let shape = (img.height() as usize, img.width() as usize);
    match img {
        DynamicImage::ImageLuma8(buf) => Ok(Array2::from_shape_fn(shape, |(r, c)| {
            (f64::from(buf.get_pixel(c as u32, r as u32)[0]) / f64::from(u8::MAX)) as f32
        })),
        DynamicImage::ImageLuma16(buf) => Ok(Array2::from_shape_fn(shape, |(r, c)| {
            (f64::from(buf.get_pixel(c as u32, r as u32)[0]) / f64::from(u16::MAX)) as f32
        })),
        other => Err(Error::NotGrey {
            path: path.to_owned(),
            color: format!("{:?}", other.color()),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(rows: usize, cols: usize) -> Array2<f32> {
        let n = (rows * cols - 1).max(1) as f32;
        Array2::from_shape_fn((rows, cols), |(r, c)| (r * cols + c) as f32 / n)
    }

    fn leftovers(dir: &Path) -> Vec<String> {
        fs::read_dir(dir)
            .expect("read dir")
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".tmp"))
            .collect()
    }

    #[test]
    fn bit_depth_parses_8_and_16_only() {
        assert_eq!("8".parse::<BitDepth>(), Ok(BitDepth::Eight));
        assert_eq!("16".parse::<BitDepth>(), Ok(BitDepth::Sixteen));
        let err = "12".parse::<BitDepth>().expect_err("12 is not a depth");
        assert!(err.to_string().contains("\"12\""), "{err}");
        assert!(" 8".parse::<BitDepth>().is_err());
        assert_eq!(BitDepth::Sixteen.to_string(), "16");
    }

    #[test]
    fn round_trip_within_quantisation() {
        let dir = tempfile::tempdir().expect("tempdir");
        // 37 x 53 with a ramp through [0, 1]: every row has a distinct value.
        let frame = ramp(37, 53);
        for (depth, max) in [(BitDepth::Eight, 255.0f32), (BitDepth::Sixteen, 65535.0)] {
            let path = dir.path().join(format!("frame_{depth}.png"));
            write_frame_png(&path, frame.view(), depth).expect("write");
            let back = read_frame_png(&path).expect("read");
            assert_eq!(back.dim(), frame.dim());
            let worst = frame
                .iter()
                .zip(back.iter())
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            // rounding to the nearest level: half a level, plus f32 slack
            assert!(
                worst <= 0.5 / max + 1e-7,
                "{depth} bit: worst error {worst}"
            );
            // and the quantisation is really that coarse (not a lossless float store)
            assert!(worst > 0.1 / max, "{depth} bit: worst error {worst}");
        }
        assert!(leftovers(dir.path()).is_empty());
    }

    #[test]
    fn levels_are_exact_at_the_grid() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("grid.png");
        let frame = Array2::from_shape_fn((2, 128), |(r, c)| (r * 128 + c) as f32 / 255.0);
        write_frame_png(&path, frame.view(), BitDepth::Eight).expect("write");
        let back = read_frame_png(&path).expect("read");
        assert_eq!(
            back,
            frame.mapv(|v| ((f64::from(v) * 255.0).round() / 255.0) as f32)
        );
    }

    #[test]
    fn out_of_range_and_nan_are_clamped() {
        let dir = tempfile::tempdir().expect("tempdir");
        let frame = Array2::from_shape_vec(
            (1, 6),
            vec![-0.5, 1.5, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.5],
        )
        .expect("shape");
        let path = dir.path().join("clamp.png");
        write_frame_png(&path, frame.view(), BitDepth::Sixteen).expect("write");
        let back = read_frame_png(&path).expect("read");
        let expected = [0.0, 1.0, 0.0, 1.0, 0.0, (32768.0f64 / 65535.0) as f32];
        assert_eq!(back.as_slice(), Some(&expected[..]));
    }

    #[test]
    fn overwrites_an_existing_frame_atomically() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("same.png");
        write_frame_png(&path, Array2::zeros((4, 4)).view(), BitDepth::Eight).expect("first");
        write_frame_png(&path, Array2::ones((4, 5)).view(), BitDepth::Eight).expect("second");
        assert_eq!(
            read_frame_png(&path).expect("read"),
            Array2::<f32>::ones((4, 5))
        );
        assert!(leftovers(dir.path()).is_empty());
    }

    #[test]
    fn missing_folder_is_an_error_naming_the_path() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("no_such_folder").join("f.png");
        let err =
            write_frame_png(&path, ramp(3, 3).view(), BitDepth::Eight).expect_err("no folder");
        assert!(matches!(err, Error::Io { .. }), "{err:?}");
        let msg = err.to_string();
        assert!(
            msg.contains("no_such_folder") && msg.contains("f.png"),
            "{msg}"
        );
        assert!(!path.exists());
    }

    #[test]
    fn empty_frame_is_a_bad_shape() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("empty.png");
        let err = write_frame_png(&path, Array2::zeros((0, 5)).view(), BitDepth::Eight)
            .expect_err("empty");
        assert!(
            matches!(
                err,
                Error::BadShape {
                    rows: 0,
                    cols: 5,
                    ..
                }
            ),
            "{err:?}"
        );
        assert!(err.to_string().contains("empty.png"));
        assert!(leftovers(dir.path()).is_empty() && !path.exists());
    }

    #[test]
    fn writes_non_contiguous_views_in_logical_order() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.png");
        let frame = ramp(5, 7);
        write_frame_png(&path, frame.t(), BitDepth::Sixteen).expect("write");
        let back = read_frame_png(&path).expect("read");
        assert_eq!(back.dim(), (7, 5));
        assert!((back[[6, 1]] - frame[[1, 6]]).abs() < 1e-5);
    }

    #[test]
    fn reading_errors_name_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let missing = dir.path().join("missing.png");
        let err = read_frame_png(&missing).expect_err("missing");
        assert!(err.to_string().contains("missing.png"), "{err}");

        let garbage = dir.path().join("garbage.png");
        fs::write(&garbage, b"not a png at all").expect("write");
        let err = read_frame_png(&garbage).expect_err("garbage");
        assert!(matches!(err, Error::Png { .. }), "{err:?}");
        assert!(err.to_string().contains("garbage.png"), "{err}");

        let rgb = dir.path().join("rgb.png");
        image::RgbImage::new(2, 2)
            .save_with_format(&rgb, image::ImageFormat::Png)
            .expect("save rgb");
        let err = read_frame_png(&rgb).expect_err("rgb");
        assert!(matches!(err, Error::NotGrey { .. }), "{err:?}");
        assert!(err.to_string().contains("rgb.png"), "{err}");
    }
}
