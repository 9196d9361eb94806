//! Buffered reading and writing of fixed-size binary words with the file offset kept, shared by
//! the RAW and DAT codecs.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use crate::error::{FormatError, Result};
use crate::header::read_some;

/// Bytes read from the source at a time.
pub(crate) const READ_CHUNK: usize = 256 * 1024;
/// Bytes a writer buffers before handing them to its sink.
pub(crate) const WRITE_CHUNK: usize = 64 * 1024;

/// A read buffer over `R` that knows the file offset of its first unread byte.
pub(crate) struct Chunked<R> {
    src: R,
    buf: Vec<u8>,
    start: usize,
    end: usize,
    offset: u64,
    eof: bool,
}

impl<R: Read> Chunked<R> {
    /// `src` starts at file offset `offset`.
    pub(crate) fn new(src: R, offset: u64) -> Self {
        Chunked {
            src,
            buf: vec![0; READ_CHUNK],
            start: 0,
            end: 0,
            offset,
            eof: false,
        }
    }

    /// Makes at least `unit` bytes available unless the source ends first.
    pub(crate) fn fill(&mut self, unit: usize, path: &Path) -> Result<()> {
        if self.end - self.start >= unit || self.eof {
            return Ok(());
        }
        self.buf.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        while self.end < unit && !self.eof {
            let n = read_some(&mut self.src, &mut self.buf[self.end..]).map_err(|source| {
                FormatError::Io {
                    path: path.to_path_buf(),
                    offset: self.offset + self.end as u64,
                    source,
                }
            })?;
            self.end += n;
            self.eof = n == 0;
        }
        Ok(())
    }

    /// The unread bytes in the buffer.
    pub(crate) fn data(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }

    /// File offset of the first unread byte.
    pub(crate) fn offset(&self) -> u64 {
        self.offset
    }

    /// Marks `n` bytes as read.
    pub(crate) fn consume(&mut self, n: usize) {
        self.start += n;
        self.offset += n as u64;
    }
}

/// A write buffer that names its sink in errors and counts bytes.
pub(crate) struct Out<W: Write> {
    w: W,
    buf: Vec<u8>,
    pub(crate) path: PathBuf,
    pub(crate) written: u64,
}

impl<W: Write> Out<W> {
    pub(crate) fn new(w: W, path: PathBuf) -> Self {
        Out {
            w,
            buf: Vec::with_capacity(WRITE_CHUNK),
            path,
            written: 0,
        }
    }

    #[inline]
    pub(crate) fn put(&mut self, bytes: &[u8]) -> Result<()> {
        self.buf.extend_from_slice(bytes);
        if self.buf.len() >= WRITE_CHUNK {
            self.flush_buf()?;
        }
        Ok(())
    }

    fn flush_buf(&mut self) -> Result<()> {
        self.w
            .write_all(&self.buf)
            .map_err(|source| FormatError::Io {
                path: self.path.clone(),
                offset: self.written,
                source,
            })?;
        self.written += self.buf.len() as u64;
        self.buf.clear();
        Ok(())
    }

    /// Writes out everything and returns the sink and the bytes written in all.
    /// Flushes and returns the sink with `summary`, its byte count filled in.
    pub(crate) fn finish_with(self, mut summary: WriteSummary) -> Result<(W, WriteSummary)> {
        let (w, bytes) = self.finish()?;
        summary.bytes = bytes;
        Ok((w, summary))
    }

    /// Bytes handed to [`Out::put`] so far: the file offset of the next byte.
    pub(crate) fn position(&self) -> u64 {
        self.written + self.buf.len() as u64
    }

    pub(crate) fn finish(mut self) -> Result<(W, u64)> {
        self.flush_buf()?;
        self.w.flush().map_err(|source| FormatError::Io {
            path: self.path.clone(),
            offset: self.written,
            source,
        })?;
        Ok((self.w, self.written))
    }

    pub(crate) fn unwritable(&self, index: u64, what: String) -> FormatError {
        FormatError::Unwritable {
            path: self.path.clone(),
            index,
            what,
        }
    }
}

/// Microseconds (from a sensor clock, unwrapped) to nanoseconds, or an error naming the offset
/// when the value does not fit an `i64` of nanoseconds (only a corrupt file gets there).
#[inline]
pub(crate) fn us_to_ns(t_us: u64, path: &Path, offset: u64) -> Result<i64> {
    i64::try_from(t_us)
        .ok()
        .and_then(|t| t.checked_mul(1000))
        .ok_or_else(|| FormatError::Corrupt {
            path: path.to_path_buf(),
            offset,
            what: format!("timestamp {t_us} us overflows i64 nanoseconds (too many clock wraps)"),
        })
}

/// What a writer wrote.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct WriteSummary {
    /// Events (or planes) written.
    pub items: u64,
    /// Bytes written, header included.
    pub bytes: u64,
    /// Events whose nanosecond timestamp was not a whole microsecond and was floored to the
    /// format's microsecond resolution.
    pub floored_timestamps: u64,
}

/// A nanosecond timestamp as whole microseconds for a µs format: floors, and says whether it had
/// to. Negative times cannot be written.
pub(crate) fn ns_to_us<W: Write>(out: &Out<W>, index: u64, t_ns: i64) -> Result<(u64, bool)> {
    if t_ns < 0 {
        return Err(out.unwritable(
            index,
            format!("timestamp {t_ns} ns is negative; the format's clock starts at 0"),
        ));
    }
    Ok(((t_ns / 1000) as u64, t_ns % 1000 != 0))
}
