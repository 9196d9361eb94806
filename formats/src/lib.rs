//! Readers and writers for real spike-camera and event-camera recordings, as the pipeline's own
//! messages: spike planes become [`SpikeChunk`]s (bit-packed, rows top-down), events become
//! [`EventBatch`]es (`t_ns`, `x`, `y`, polarity ±1). No dora here: this is a plain library.
//!
//! | module | format | read | write |
//! |---|---|---|---|
//! | [`pku`] | PKU Vidar spike `.dat` (headerless planes, rows bottom-up) | [`pku::PkuReader`] | [`pku::PkuWriter`] |
//! | [`text`] | Event Camera Dataset `t_seconds x y polarity` text | [`text::TextReader`] | [`text::TextWriter`] |
//! | [`raw`] | Prophesee RAW, EVT 2.0 ([`evt2`]) and EVT 3.0 ([`evt3`]) | [`raw::RawReader`] | [`raw::Evt2Writer`], [`raw::Evt3Writer`] |
//! | [`dat`] | Prophesee DAT CD events (N-CARS, Gen1) | [`dat::DatReader`] | [`dat::DatWriter`] |
//! | [`truth`] | ground-truth folders: PNG frames listed by plane in `timestamps.txt` | [`truth::TruthList`] | [`truth::TruthListWriter`] |
//! | [`aedat4`] | AEDAT 4 (iniVation DV): events and APS frames, uncompressed, LZ4 or Zstd | [`aedat4::Aedat4Reader`], [`aedat4::Aedat4Frames`] | [`aedat4::Aedat4Writer`] (none or LZ4) |
//! | [`npy`] | NumPy `.npy` float32 `[T, H, W]` intensity frames (video for `frames-to-events`) | [`npy::NpyFrames`] | |
//!
//! Every reader streams with bounded memory (a 10 GB file is never loaded whole): spike readers
//! hand out chunks of N planes, event readers fill batches of up to N events
//! ([`EventReader::read_into`], [`EventReader::next_chunk`], [`EventReader::into_chunks`]).
//! [`sniff()`] tells the formats apart by content (a `.dat` may be PKU spikes or Prophesee events);
//! [`info()`] summarises any file; [`open_events`] opens any event file.
//!
//! Bad input gives a [`FormatError`] naming the file, the byte offset or line, and the value,
//! after everything decoded before the fault has been delivered. Repairs are opt-in and counted
//! ([`ReadOptions`], [`ReadStats`]). Timestamps are integers with their unit in the name.
//!
//! ```
//! use neuspike_formats::{EventReader, ReadOptions, Resolution, text::{TextReader, TextWriter}};
//! use neuspike_formats::Event;
//!
//! let mut w = TextWriter::new(Vec::new(), "mem", Resolution::new(240, 180), true).unwrap();
//! w.write_event(&Event { t_ns: 2_097_134_001, x: 162, y: 27, polarity: -1 }).unwrap();
//! let (bytes, _) = w.finish().unwrap();
//! assert_eq!(bytes, b"240 180\n2.097134001 162 27 0\n");
//!
//! let mut r = TextReader::from_reader(&bytes[..], "mem", &ReadOptions::default()).unwrap();
//! let batch = r.next_chunk(100).unwrap().unwrap();
//! assert_eq!(batch.get(0), Event { t_ns: 2_097_134_001, x: 162, y: 27, polarity: -1 });
//! ```
#![deny(missing_docs)]

pub mod aedat4;
pub mod atomic;
mod binary;
pub mod dat;
pub mod error;
mod events;
pub mod evt2;
pub mod evt3;
#[cfg(feature = "hdf5")]
pub mod hdf5;
pub mod header;
pub mod info;
pub mod npy;
mod open;
pub mod pku;
pub mod raw;
pub mod sniff;
pub mod text;
pub mod truth;

use std::path::Path;

pub use binary::WriteSummary;
pub use error::{FormatError, Location, Result};
pub use events::{
    Disorder, Drained, EventChunks, EventReader, ReadOptions, ReadStats, Resolution, UnknownWords,
    drain_checked, read_all,
};
pub use header::EvtVersion;
pub use info::{EventInfo, Info, event_info, info};
pub use neuspike_schemas::{Event, EventBatch, SpikeChunk, bytes_per_plane};
pub use open::{open_event_format, open_events};
pub use sniff::{Format, sniff};

/// What every event writer does: append events in time order (`write_batch` appends a batch
/// event by event unless the format packs runs).
pub trait EventWriter {
    /// Appends one event.
    fn write_event(&mut self, e: &Event) -> Result<()>;

    /// Appends every event of a batch.
    fn write_batch(&mut self, b: &EventBatch) -> Result<()> {
        for i in 0..b.len() {
            self.write_event(&b.get(i))?;
        }
        Ok(())
    }
}

/// Opens the file at `path`; the error names it.
pub(crate) fn open_file(path: &Path) -> Result<std::fs::File> {
    std::fs::File::open(path).map_err(|source| FormatError::Open {
        path: path.to_path_buf(),
        source,
    })
}
