//! The sink stage: frames written as PNG, scored against the ground truth and summarised. Nothing
//! here knows about dora; the node binary (`main.rs`) decodes its inputs and hands the frames to a
//! [`Sink`], which writes, scores and summarises them with `neuspike-image` (PNG) and
//! `neuspike-metrics` (PSNR, SSIM, 2D entropy).
//!
//! - [`report`]: `metrics.csv` (one row a frame, flushed each row) and the per-method summary.
#![deny(missing_docs)]

use std::path::PathBuf;

pub mod report;
mod stage;
mod writer;

pub use neuspike_image::BitDepth;
pub use neuspike_metrics::MetricsError;
pub use report::{FrameMetrics, MetricsCsv, Summary, SummaryFile, read_run};
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
    /// Writing a frame as a PNG, or reading one back, failed.
    #[error(transparent)]
    Image(#[from] neuspike_image::Error),
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
    /// A run's output read back is not whole: the run did not finish, failed, or its
    /// `metrics.csv` was cut ([`report::read_run`]).
    #[error("{}: {what}", dir.display())]
    NotWhole {
        /// The sink's folder.
        dir: PathBuf,
        /// What is missing or cut, and why.
        what: String,
    },
}
