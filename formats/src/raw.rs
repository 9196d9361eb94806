//! Prophesee RAW files: a `%` header ([`crate::header`]) naming the encoding, then EVT 2.0
//! ([`crate::evt2`]) or EVT 3.0 ([`crate::evt3`]) words to the end of the file.

use std::fs::File;
use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};

use neuspike_schemas::EventBatch;

use crate::binary::Chunked;
use crate::error::{FormatError, Result};
use crate::events::{Bounds, EventReader, ReadOptions, Resolution, Sink};
use crate::evt2::{self, Evt2Decoder};
use crate::evt3::{self, Evt3Decoder};
use crate::header::{AfterHeader, EvtVersion, PropheseeHeader, read_header, resolve_resolution};

pub use crate::evt2::Evt2Writer;
pub use crate::evt3::Evt3Writer;

enum Decoder {
    Evt2(Evt2Decoder),
    Evt3(Evt3Decoder),
}

/// A streaming reader of Prophesee RAW EVT 2.0 / EVT 3.0 files.
///
/// The sensor size comes from the header (`geometry` or `format ...;width=;height=`) or, for
/// files whose header does not say (older recordings with only `% evt 2.0`), from
/// [`ReadOptions::resolution`].
pub struct RawReader<R: Read> {
    header: PropheseeHeader,
    version: EvtVersion,
    stream: Chunked<AfterHeader<R>>,
    decoder: Decoder,
    sink: Sink,
}

impl RawReader<File> {
    /// Opens a RAW file.
    pub fn open(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<Self> {
        let path = path.as_ref();
        let file = crate::open_file(path)?;
        Self::from_reader(file, path, opts)
    }
}

impl<R: Read> RawReader<R> {
    /// Reads a RAW stream from `r`, named `name` in errors.
    pub fn from_reader(mut r: R, name: impl Into<PathBuf>, opts: &ReadOptions) -> Result<Self> {
        let path: PathBuf = name.into();
        let allow_unknown_size = opts.allow_unknown_size;
        let (header, rest) = read_header(&mut r, &path)?;
        if header.lines.is_empty() && !header.explicit_end {
            if rest.is_empty() {
                return Err(FormatError::Empty { path });
            }
            return Err(FormatError::Header {
                path,
                what: "no `%` header: not a Prophesee RAW file".into(),
            });
        }
        let version = header.evt.ok_or_else(|| FormatError::Header {
            path: path.clone(),
            what: "names no event encoding (no `% evt` or `% format` line)".into(),
        })?;
        let decoder = match version {
            EvtVersion::Evt2 => Decoder::Evt2(Evt2Decoder::default()),
            EvtVersion::Evt3 => Decoder::Evt3(Evt3Decoder::default()),
            EvtVersion::Evt21 => {
                return Err(FormatError::Unsupported {
                    path,
                    what: "EVT 2.1 encoding (only EVT 2.0 and EVT 3.0 are decoded)".into(),
                });
            }
        };
        let resolution = resolve_resolution(
            header.resolution,
            opts.resolution,
            &path,
            allow_unknown_size,
            "the RAW header has no `% geometry` or `% format ...;width=;height=` line",
        )?;
        let bounds = resolution.map_or(Bounds::Unknown, Bounds::Sensor);
        let offset = header.data_offset;
        Ok(RawReader {
            header,
            version,
            stream: Chunked::new(Cursor::new(rest).chain(r), offset),
            decoder,
            sink: Sink::new(path, bounds, opts),
        })
    }

    /// The sensor size, when the file or the options give one.
    pub(crate) fn known_resolution(&self) -> Option<Resolution> {
        self.sink.known
    }

    /// The header.
    pub fn header(&self) -> &PropheseeHeader {
        &self.header
    }

    /// The encoding.
    pub fn version(&self) -> EvtVersion {
        self.version
    }
}

impl<R: Read> EventReader for RawReader<R> {
    crate::events::sink_accessors!();

    fn read_into(&mut self, out: &mut EventBatch, max: usize) -> Result<usize> {
        let stream = &mut self.stream;
        let decoder = &mut self.decoder;
        let (word, name) = match decoder {
            Decoder::Evt2(_) => (evt2::WORD_BYTES, "EVT 2.0"),
            Decoder::Evt3(_) => (evt3::WORD_BYTES, "EVT 3.0"),
        };
        self.sink.read_with(out, max, |sink, out| {
            while !sink.full() {
                stream.fill(word, &sink.path)?;
                let avail = stream.data().len();
                if avail < word {
                    if avail > 0 {
                        return Err(FormatError::Truncated {
                            path: sink.path.clone(),
                            offset: stream.offset(),
                            what: format!("{avail} byte(s) of a {word}-byte {name} word"),
                        });
                    }
                    sink.finish();
                    return Ok(());
                }
                let whole = avail - avail % word;
                let data = &stream.data()[..whole];
                let offset = stream.offset();
                let n = match decoder {
                    Decoder::Evt2(d) => d.decode(data, offset, sink, out)?,
                    Decoder::Evt3(d) => d.decode(data, offset, sink, out)?,
                };
                stream.consume(n);
            }
            Ok(())
        })
    }
}
