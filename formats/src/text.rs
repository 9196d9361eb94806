//! The Event Camera Dataset text format: one event a line, `t_seconds x y polarity`, fields
//! separated by spaces or tabs, polarity `0` (OFF) or `1` (ON), and optionally a first line
//! `width height`. Blank lines and lines starting with `#` are skipped (and counted).
//!
//! Times are decimal seconds and become integer nanoseconds digit by digit, never through a
//! float: `2.097134001` is exactly 2,097,134,001 ns. Digits past the ninth decimal are rounded
//! half up on the tenth (`2.1957200009999998` -> 2,195,720,001 ns). Signs, exponents and anything
//! else but digits and one `.` are errors that quote the line.
//!
//! A line longer than [`ReadOptions::max_line_bytes`] (by default [`MAX_LINE_BYTES`]), such as
//! a binary file without a line feed, is an error naming the line once that many bytes have
//! been read: it is never gathered whole.

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};

use neuspike_schemas::{Event, EventBatch};

use crate::binary::{Out, WriteSummary};
use crate::error::{FormatError, Location, Result};
use crate::events::{Bounds, EventReader, ReadOptions, Resolution, Sink};
use crate::header::resolve_resolution;

const NS_PER_S: i64 = 1_000_000_000;
/// Longest quote of a bad line in an error message.
const QUOTE_MAX: usize = 80;
pub use crate::events::MAX_LINE_BYTES;

/// Reads the next line of `r` (with its line feed) into `line` and returns its bytes, 0 at the
/// end. A line of more than `max` bytes before its line feed is an error naming `line_no`, its
/// number, after `max + 1` bytes: memory stays bounded by `max`. `offset` is where it starts.
fn read_line_bounded<R: BufRead>(
    r: &mut R,
    line: &mut Vec<u8>,
    max: usize,
    path: &Path,
    line_no: u64,
    offset: u64,
) -> Result<usize> {
    line.clear();
    let n = r
        .by_ref()
        .take((max as u64).saturating_add(1))
        .read_until(b'\n', line)
        .map_err(|source| FormatError::Io {
            path: path.to_path_buf(),
            offset,
            source,
        })?;
    if n > max && line.last() != Some(&b'\n') {
        return Err(FormatError::Text {
            path: path.to_path_buf(),
            line: line_no,
            what: format!(
                "longer than {max} bytes (no line feed in its first {n} bytes, from byte \
                 {offset}); an event line is under 100 bytes (text::MAX_LINE_BYTES, \
                 ReadOptions::max_line_bytes)"
            ),
        });
    }
    Ok(n)
}

/// Parses decimal seconds into nanoseconds without floating point; see the module docs.
///
/// ```
/// use neuspike_formats::text::parse_seconds_ns;
/// assert_eq!(parse_seconds_ns(b"2.097134001"), Ok(2_097_134_001));
/// assert_eq!(parse_seconds_ns(b"2.09714"), Ok(2_097_140_000));
/// assert_eq!(parse_seconds_ns(b"2.1957200009999998"), Ok(2_195_720_001));
/// assert!(parse_seconds_ns(b"1e-3").is_err());
/// ```
pub fn parse_seconds_ns(field: &[u8]) -> std::result::Result<i64, String> {
    let bad = || format!("`{}` is not a decimal number of seconds", quote(field));
    let (int, frac) = match field.iter().position(|&b| b == b'.') {
        Some(i) => (&field[..i], &field[i + 1..]),
        None => (field, &[][..]),
    };
    if int.is_empty() && frac.is_empty() {
        return Err(bad());
    }
    if !int.iter().chain(frac).all(u8::is_ascii_digit) {
        return Err(bad());
    }
    let too_big = || format!("`{}` seconds overflows i64 nanoseconds", quote(field));
    let mut secs: i64 = 0;
    for &d in int {
        secs = secs
            .checked_mul(10)
            .and_then(|s| s.checked_add(i64::from(d - b'0')))
            .ok_or_else(too_big)?;
    }
    let mut ns: i64 = 0;
    for i in 0..9 {
        ns = ns * 10 + frac.get(i).map_or(0, |&d| i64::from(d - b'0'));
    }
    if frac.get(9).is_some_and(|&d| d >= b'5') {
        ns += 1;
    }
    secs.checked_mul(NS_PER_S)
        .and_then(|s| s.checked_add(ns))
        .ok_or_else(too_big)
}

fn parse_uint(field: &[u8]) -> Option<u64> {
    if field.is_empty() || field.len() > 19 || !field.iter().all(u8::is_ascii_digit) {
        return None;
    }
    Some(
        field
            .iter()
            .fold(0u64, |v, &d| v * 10 + u64::from(d - b'0')),
    )
}

fn quote(bytes: &[u8]) -> String {
    let s = String::from_utf8_lossy(bytes);
    let s = s.trim_end();
    if s.chars().count() > QUOTE_MAX {
        format!("{}...", s.chars().take(QUOTE_MAX).collect::<String>())
    } else {
        s.to_string()
    }
}

fn fields(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(u8::is_ascii_whitespace)
        .filter(|f| !f.is_empty())
}

/// One parsed line.
enum Line {
    Skip,
    Size(Resolution),
    Event { t_ns: i64, x: u32, y: u32, on: bool },
}

/// Parses one line; `allow_size` admits a `width height` line.
fn parse_line(line: &[u8], allow_size: bool) -> std::result::Result<Line, LineError> {
    let trimmed = line.trim_ascii();
    if trimmed.is_empty() || trimmed[0] == b'#' {
        return Ok(Line::Skip);
    }
    let mut f = [&[][..]; 4];
    let mut n = 0;
    for field in fields(trimmed) {
        if n < 4 {
            f[n] = field;
        }
        n += 1;
    }
    if n == 2 && allow_size {
        let dim = |v: &[u8]| {
            parse_uint(v)
                .and_then(|v| u16::try_from(v).ok())
                .filter(|&v| v > 0)
        };
        return match (dim(f[0]), dim(f[1])) {
            (Some(w), Some(h)) => Ok(Line::Size(Resolution::new(w, h))),
            _ => Err(LineError::Text(format!(
                "`{}` is not a `width height` line",
                quote(trimmed)
            ))),
        };
    }
    if n != 4 {
        return Err(LineError::Text(format!(
            "expected 4 fields `t_seconds x y polarity`, found {n}: `{}`",
            quote(trimmed)
        )));
    }
    let t_ns = parse_seconds_ns(f[0]).map_err(LineError::Text)?;
    let coord = |v: &[u8], name: &str| {
        parse_uint(v)
            .and_then(|v| u32::try_from(v).ok())
            .ok_or_else(|| LineError::Text(format!("{name} `{}` is not a pixel index", quote(v))))
    };
    let x = coord(f[1], "x")?;
    let y = coord(f[2], "y")?;
    let on = match f[3] {
        b"0" => false,
        b"1" => true,
        other => {
            return Err(
                match std::str::from_utf8(other)
                    .ok()
                    .and_then(|s| s.parse::<i64>().ok())
                {
                    Some(v) => LineError::Polarity(v),
                    None => LineError::Text(format!("polarity `{}` is not 0 or 1", quote(other))),
                },
            );
        }
    };
    Ok(Line::Event { t_ns, x, y, on })
}

enum LineError {
    Text(String),
    Polarity(i64),
}

/// A streaming reader of Event Camera Dataset text files.
pub struct TextReader<R: BufRead> {
    r: R,
    line: Vec<u8>,
    line_no: u64,
    bytes_read: u64,
    /// The first line, when it was an event line read while looking for the size line.
    held: Option<(Vec<u8>, u64)>,
    size_line: Option<Resolution>,
    /// The longest line accepted ([`ReadOptions::max_line_bytes`]).
    max_line: usize,
    sink: Sink,
}

impl TextReader<BufReader<File>> {
    /// Opens a text file.
    pub fn open(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<Self> {
        let path = path.as_ref();
        let file = crate::open_file(path)?;
        Self::from_reader(BufReader::with_capacity(256 * 1024, file), path, opts)
    }
}

impl<R: BufRead> TextReader<R> {
    /// Reads text from `r`, named `name` in errors.
    pub fn from_reader(r: R, name: impl Into<PathBuf>, opts: &ReadOptions) -> Result<Self> {
        let path: PathBuf = name.into();
        let allow_unknown_size = opts.allow_unknown_size;
        let mut reader = TextReader {
            r,
            line: Vec::new(),
            line_no: 0,
            bytes_read: 0,
            held: None,
            size_line: None,
            max_line: opts.max_line_bytes,
            // Replaced below once the size is known.
            sink: Sink::new(path.clone(), Bounds::Unknown, opts),
        };
        let mut skipped = 0;
        loop {
            if !reader.next_line(&path)? {
                if reader.bytes_read == 0 {
                    return Err(FormatError::Empty { path });
                }
                break;
            }
            match parse_line(&reader.line, true) {
                Ok(Line::Skip) => skipped += 1,
                Ok(Line::Size(r)) => {
                    reader.size_line = Some(r);
                    break;
                }
                // An event line, or a bad one: decoded (and reported) in order by read_into.
                _ => {
                    reader.held = Some((std::mem::take(&mut reader.line), reader.line_no));
                    break;
                }
            }
        }
        let resolution = resolve_resolution(
            reader.size_line,
            opts.resolution,
            &path,
            allow_unknown_size,
            "the text has no `width height` first line",
        )?;
        reader.sink = Sink::new(
            path,
            resolution.map_or(Bounds::Unknown, Bounds::Sensor),
            opts,
        );
        reader.sink.stats.lines_skipped = skipped;
        Ok(reader)
    }

    /// The sensor size, when the file or the options give one.
    pub(crate) fn known_resolution(&self) -> Option<Resolution> {
        self.sink.known
    }

    /// The size stated by the file's first line, if it has one.
    pub fn size_line(&self) -> Option<Resolution> {
        self.size_line
    }

    /// Reads the next line into `self.line`; false at the end.
    fn next_line(&mut self, path: &Path) -> Result<bool> {
        let n = read_line_bounded(
            &mut self.r,
            &mut self.line,
            self.max_line,
            path,
            self.line_no + 1,
            self.bytes_read,
        )?;
        self.bytes_read += n as u64;
        if n > 0 {
            self.line_no += 1;
        }
        Ok(n > 0)
    }
}

fn line_event(sink: &mut Sink, out: &mut EventBatch, line: &[u8], line_no: u64) -> Result<()> {
    let at = Location::Line(line_no);
    match parse_line(line, false) {
        Ok(Line::Event { t_ns, x, y, on }) => sink.emit(out, t_ns, x, y, on, at),
        Ok(_) => {
            sink.stats.lines_skipped += 1;
            Ok(())
        }
        Err(LineError::Text(what)) => Err(FormatError::Text {
            path: sink.path.clone(),
            line: line_no,
            what,
        }),
        Err(LineError::Polarity(value)) => Err(FormatError::Polarity {
            path: sink.path.clone(),
            at,
            value,
        }),
    }
}

impl<R: BufRead> EventReader for TextReader<R> {
    crate::events::sink_accessors!();

    fn read_into(&mut self, out: &mut EventBatch, max: usize) -> Result<usize> {
        let Self {
            r,
            line,
            line_no,
            bytes_read,
            held,
            sink,
            max_line,
            ..
        } = self;
        sink.read_with(out, max, |sink, out| {
            if let Some((l, n)) = held.take() {
                line_event(sink, out, &l, n)?;
            }
            while !sink.full() {
                let n =
                    read_line_bounded(r, line, *max_line, &sink.path, *line_no + 1, *bytes_read)?;
                if n == 0 {
                    sink.finish();
                    return Ok(());
                }
                *bytes_read += n as u64;
                *line_no += 1;
                line_event(sink, out, line, *line_no)?;
            }
            Ok(())
        })
    }
}

/// Writes events as Event Camera Dataset text: optionally a `width height` first line, then
/// `seconds.nanoseconds x y polarity` with nine decimals, polarity `1` for ON and `0` for OFF.
pub struct TextWriter<W: Write> {
    out: Out<W>,
    resolution: Resolution,
    last_t_ns: Option<i64>,
    line: Vec<u8>,
    summary: WriteSummary,
}

impl<W: Write> TextWriter<W> {
    /// Starts a file on `w` (named `name` in errors); `size_line` writes the `width height` line.
    pub fn new(
        w: W,
        name: impl Into<PathBuf>,
        resolution: Resolution,
        size_line: bool,
    ) -> Result<Self> {
        let mut out = Out::new(w, name.into());
        if size_line {
            out.put(format!("{} {}\n", resolution.width, resolution.height).as_bytes())?;
        }
        Ok(TextWriter {
            out,
            resolution,
            last_t_ns: None,
            line: Vec::with_capacity(64),
            summary: WriteSummary::default(),
        })
    }

    /// Appends one event; events must come in non-decreasing time order, at `t_ns >= 0`.
    pub fn write_event(&mut self, e: &Event) -> Result<()> {
        let index = self.summary.items;
        let r = self.resolution;
        let fail = |what: String| Err(self.out.unwritable(index, what));
        if e.t_ns < 0 {
            return fail(format!("timestamp {} ns is negative", e.t_ns));
        }
        if let Some(last) = self.last_t_ns
            && e.t_ns < last
        {
            return fail(format!(
                "timestamp {} ns is earlier than the previous event's {last} ns",
                e.t_ns
            ));
        }
        if e.x >= r.width || e.y >= r.height {
            return fail(format!("({}, {}) is outside the {r} sensor", e.x, e.y));
        }
        let p = match e.polarity {
            1 => 1,
            -1 => 0,
            p => return fail(format!("polarity {p} is not +1 or -1")),
        };
        self.line.clear();
        // Writing to a Vec cannot fail.
        let _ = writeln!(
            self.line,
            "{}.{:09} {} {} {p}",
            e.t_ns / NS_PER_S,
            e.t_ns % NS_PER_S,
            e.x,
            e.y
        );
        self.out.put(&self.line)?;
        self.last_t_ns = Some(e.t_ns);
        self.summary.items += 1;
        Ok(())
    }

    /// Flushes and returns the sink and what was written.
    pub fn finish(self) -> Result<(W, WriteSummary)> {
        self.out.finish_with(self.summary)
    }
}

impl<W: Write> crate::EventWriter for TextWriter<W> {
    fn write_event(&mut self, e: &Event) -> Result<()> {
        TextWriter::write_event(self, e)
    }
}
