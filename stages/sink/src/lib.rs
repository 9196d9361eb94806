//! The pure library behind neuspike's sink node: image-quality metrics, PNG frame output and the
//! run report. Nothing here knows about dora; the node binary (`main.rs`) decodes its inputs and
//! hands the frames to a [`Sink`], which writes, scores and summarises them.
//!
//! - [`metrics`]: PSNR, PSNR after a least-squares gain, SSIM and 2D entropy, exactly as defined
//!   in `docs/definitions.md` (f64 accumulation throughout).
//! - [`png_out`]: grey 8- or 16-bit PNG frames, written atomically, and read back.
//! - [`report`]: `metrics.csv` (one row a frame, flushed each row) and the per-method summary.
//!
//! ```
//! use ndarray::Array2;
//! use neuspike_sink::metrics;
//!
//! let gt = Array2::<f32>::from_elem((16, 16), 0.25);
//! let x = Array2::<f32>::from_elem((16, 16), 0.75);
//! metrics::check_same_shape(x.view(), gt.view()).expect("same shape");
//! // MSE = 0.25, so PSNR = 10 log10(4)
//! assert!((metrics::psnr(x.view(), gt.view()) - 10.0 * 4f64.log10()).abs() < 1e-12);
//! assert_eq!(metrics::psnr(gt.view(), gt.view()), f64::INFINITY);
//! ```
#![deny(missing_docs)]

use std::path::PathBuf;

pub mod metrics;
pub mod png_out;
pub mod report;
mod stage;
mod writer;

pub use metrics::MetricsError;
pub use png_out::BitDepth;
pub use report::{FrameMetrics, MetricsCsv, Summary};
pub use stage::SinkStage;
pub use writer::{GROUND_TRUTH, InputTally, Sink, SinkConfig};

/// What can go wrong while the sink writes or reads its files. Every message names the file; the
/// cause is the error's source (printed after it in a chain, never twice).
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
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
    /// Two images given to a metric differ in shape.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    /// The summary could not be written: the counts it held, on one line, so that they still
    /// reach the user (on stderr, with the error).
    #[error("{what}; the frames per input: {counts}")]
    SummaryLost {
        /// Why it could not be written.
        what: String,
        /// Every input's counts, one line.
        counts: String,
    },
}
