//! AEDAT 4 (iniVation DV: DAVIS, DVXplorer): events, and the APS frames a DAVIS records beside
//! them (ground truth for real data).
//!
//! The layout, as DV and dv-processing write it:
//!
//! | bytes | what |
//! |---|---|
//! | 14 | `#!AER-DAT4.0\r\n` |
//! | 4 + n | `u32` n, then the FlatBuffers `IOHeader` (identifier `IOHE`): `compression` (0 none, 1 LZ4, 2 LZ4 high, 3 Zstd, 4 Zstd high), `dataTablePosition` (`i64`, -1 when absent), `infoNode` (XML naming each stream's id, type and, for events and frames, `sizeX` / `sizeY`) |
//! | 8 + m, repeated | a packet: `i32` stream id, `u32` m, then m bytes: a size-prefixed FlatBuffer, compressed as the header says (LZ4 frames or Zstandard frames) |
//! | the rest | from `dataTablePosition` on, the packet index DV writes at close (not read: packets are read in order) |
//!
//! Packet payloads carry a file identifier: `EVTS` (a vector of 16-byte `Event` structs:
//! `i64` t µs, `i16` x, `i16` y, `u8` polarity 0/1), `FRME` (a `Frame` table: timestamps in µs,
//! format, size, position and pixel bytes), `IMUS`, `TRIG` and others. [`Aedat4Reader`] delivers
//! the events of one `EVTS` stream and skips (and counts) every other packet without decompressing
//! it; [`Aedat4Frames`] delivers the frames of one `FRME` stream. [`Aedat4Writer`] writes an
//! `EVTS` stream (id 0) and a `FRME` stream (id 1), uncompressed or in LZ4 frames, with no packet
//! index (`dataTablePosition` -1, which dv-processing accepts and indexes by scanning).
//!
//! The FlatBuffers are read by a small checked reader of our own ([`fb`]), not the `flatbuffers`
//! crate: its accessors for hand-written tables need `unsafe` implementations, and every offset
//! here is bounds-checked instead.
//!
//! Hostile bytes: nothing is allocated from what a length field claims. Every size read from the
//! file (the `IOHeader`'s length, a packet's size, a vector's element count, a frame's size) is
//! checked against the bytes that are there (the file's length, when the reader opened the file
//! itself; the packet's bytes for what lies inside a packet) and against a stated limit
//! ([`MAX_HEADER_BYTES`], [`ReadOptions::max_packet_bytes`], by default [`MAX_PACKET_BYTES`])
//! before anything is allocated, and stored bytes are read as they come, never into a buffer
//! sized by the claim. A compressed payload is read through a reader that stops one byte past
//! the packet limit (a decompression bomb is an error naming the limit, not an allocation), and
//! a Zstandard frame that asks for a window larger than the limit is refused before decoding.
//! Memory is thus bounded by one packet of at most the limit.
//!
//! Bad input: every error names the file and the byte offset of the packet (or header field) at
//! fault, and the value: a wrong magic, a header that is not an `IOHeader`, an unknown
//! compression, a stream id the description does not declare, a packet whose identifier does not
//! match its stream, a truncated packet, a payload that does not decompress, a vector that runs
//! past its packet, an event outside the sensor or with a polarity byte other than 0 or 1, a
//! frame whose pixel count does not match its size and format.

use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};

use neuspike_schemas::{Event, EventBatch};

use crate::binary::{Out, WriteSummary, ns_to_us, us_to_ns};
use crate::error::{FormatError, Location, Result};
use crate::events::{BLOCK_EVENTS, Bounds, EventReader, ReadOptions, Resolution, Sink};
use crate::header::resolve_resolution;

/// The first bytes of every AEDAT 4 file.
pub const MAGIC: &[u8; 14] = b"#!AER-DAT4.0\r\n";
pub use crate::events::MAX_PACKET_BYTES;
/// The most bytes the `IOHeader` may take: 16 MiB. It holds the XML description of the streams,
/// a few KB in DV's files; a longer claim is an error naming this limit.
pub const MAX_HEADER_BYTES: usize = 16 << 20;
/// Bytes of one `Event` struct in an `EVTS` packet.
const EVENT_BYTES: usize = 16;
/// Events per packet the writer emits.
pub const EVENTS_PER_PACKET: usize = 8192;

/// How packet payloads are compressed (the `IOHeader`'s `compression`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Stored as is.
    None,
    /// LZ4 frames (DV's `LZ4` and `LZ4_HIGH`).
    Lz4,
    /// Zstandard frames (DV's `ZSTD` and `ZSTD_HIGH`; read only).
    Zstd,
}

impl Compression {
    fn from_code(code: i32) -> Option<Self> {
        match code {
            0 => Some(Compression::None),
            1 | 2 => Some(Compression::Lz4),
            3 | 4 => Some(Compression::Zstd),
            _ => None,
        }
    }

    fn code(self) -> i32 {
        match self {
            Compression::None => 0,
            Compression::Lz4 => 1,
            Compression::Zstd => 3,
        }
    }
}

/// One stream the file's description declares.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StreamInfo {
    /// The id its packets carry.
    pub id: i32,
    /// Its FlatBuffers identifier: `EVTS`, `FRME`, `IMUS`, `TRIG`, ...
    pub kind: String,
    /// `sizeX` x `sizeY`, for event and frame streams.
    pub resolution: Option<Resolution>,
}

/// What the start of an AEDAT 4 file says.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Aedat4Header {
    /// How packets are compressed.
    pub compression: Compression,
    /// Where the packet index starts (packets end there), when the file has one.
    pub data_table_position: Option<u64>,
    /// The declared streams, in the description's order.
    pub streams: Vec<StreamInfo>,
    /// The file offset of the first packet.
    pub data_offset: u64,
}

impl Aedat4Header {
    /// The first stream of kind `kind`.
    pub fn first(&self, kind: &str) -> Option<&StreamInfo> {
        self.streams.iter().find(|s| s.kind == kind)
    }
}

/// A checked FlatBuffers reader: every read is bounds-checked and returns `None` past the end.
pub(crate) mod fb {
    /// A little-endian value at `pos`.
    pub(crate) fn u16_at(b: &[u8], pos: usize) -> Option<u16> {
        Some(u16::from_le_bytes(
            b.get(pos..pos.checked_add(2)?)?.try_into().ok()?,
        ))
    }
    pub(crate) fn u32_at(b: &[u8], pos: usize) -> Option<u32> {
        Some(u32::from_le_bytes(
            b.get(pos..pos.checked_add(4)?)?.try_into().ok()?,
        ))
    }
    pub(crate) fn i32_at(b: &[u8], pos: usize) -> Option<i32> {
        Some(i32::from_le_bytes(
            b.get(pos..pos.checked_add(4)?)?.try_into().ok()?,
        ))
    }
    pub(crate) fn i64_at(b: &[u8], pos: usize) -> Option<i64> {
        Some(i64::from_le_bytes(
            b.get(pos..pos.checked_add(8)?)?.try_into().ok()?,
        ))
    }

    /// A table: its position and its vtable's.
    #[derive(Clone, Copy)]
    pub(crate) struct Table<'a> {
        b: &'a [u8],
        pos: usize,
        vtable: usize,
        vtable_len: usize,
    }

    impl<'a> Table<'a> {
        /// The root table of buffer `b` (the `u32` at 0 points at it).
        pub(crate) fn root(b: &'a [u8]) -> Option<Self> {
            Self::at(b, usize::try_from(u32_at(b, 0)?).ok()?)
        }

        fn at(b: &'a [u8], pos: usize) -> Option<Self> {
            let soffset = i64::from(i32_at(b, pos)?);
            let vtable = usize::try_from(i64::try_from(pos).ok()?.checked_sub(soffset)?).ok()?;
            let vtable_len = usize::from(u16_at(b, vtable)?);
            if vtable_len < 4 || vtable_len % 2 != 0 || vtable.checked_add(vtable_len)? > b.len() {
                return None;
            }
            let table_len = usize::from(u16_at(b, vtable + 2)?);
            if pos.checked_add(table_len.max(4))? > b.len() {
                return None;
            }
            Some(Table {
                b,
                pos,
                vtable,
                vtable_len,
            })
        }

        /// Where field `slot` lies, `None` when absent (its default applies).
        fn field(&self, slot: usize) -> Option<usize> {
            let entry = 4 + 2 * slot;
            if entry + 2 > self.vtable_len {
                return None;
            }
            match u16_at(self.b, self.vtable + entry)? {
                0 => None,
                off => self.pos.checked_add(usize::from(off)),
            }
        }

        /// A scalar field: `Ok(default)` when absent, `Err(())` when it runs past the buffer.
        pub(crate) fn i64(&self, slot: usize, default: i64) -> Result<i64, ()> {
            match self.field(slot) {
                None => Ok(default),
                Some(p) => i64_at(self.b, p).ok_or(()),
            }
        }
        pub(crate) fn i32(&self, slot: usize, default: i32) -> Result<i32, ()> {
            match self.field(slot) {
                None => Ok(default),
                Some(p) => i32_at(self.b, p).ok_or(()),
            }
        }
        pub(crate) fn i16(&self, slot: usize, default: i16) -> Result<i16, ()> {
            match self.field(slot) {
                None => Ok(default),
                Some(p) => Ok(i16::from_le_bytes(
                    self.b
                        .get(p..p.checked_add(2).ok_or(())?)
                        .ok_or(())?
                        .try_into()
                        .map_err(|_| ())?,
                )),
            }
        }
        pub(crate) fn i8(&self, slot: usize, default: i8) -> Result<i8, ()> {
            match self.field(slot) {
                None => Ok(default),
                Some(p) => self.b.get(p).map(|&v| v as i8).ok_or(()),
            }
        }

        /// A vector field: `Ok(None)` when absent, else its element count and the position of
        /// its first element (`len * elem` bytes checked to lie inside the buffer).
        pub(crate) fn vector(
            &self,
            slot: usize,
            elem: usize,
        ) -> Result<Option<(usize, usize)>, ()> {
            let Some(p) = self.field(slot) else {
                return Ok(None);
            };
            let target = p
                .checked_add(usize::try_from(u32_at(self.b, p).ok_or(())?).map_err(|_| ())?)
                .ok_or(())?;
            let len = usize::try_from(u32_at(self.b, target).ok_or(())?).map_err(|_| ())?;
            let start = target + 4;
            let end = len
                .checked_mul(elem)
                .and_then(|n| start.checked_add(n))
                .ok_or(())?;
            if end > self.b.len() {
                return Err(());
            }
            Ok(Some((len, start)))
        }

        /// A string field (UTF-8 checked).
        pub(crate) fn str(&self, slot: usize) -> Result<Option<&'a str>, ()> {
            match self.vector(slot, 1)? {
                None => Ok(None),
                Some((len, start)) => {
                    std::str::from_utf8(self.b.get(start..start + len).ok_or(())?)
                        .map(Some)
                        .map_err(|_| ())
                }
            }
        }
    }
}

/// Reads the magic, the `IOHeader` and the description; returns the header. `file_len`, when
/// known, is the file's size: a header length beyond it is refused before anything is read.
fn read_header<R: Read>(r: &mut R, path: &Path, file_len: Option<u64>) -> Result<Aedat4Header> {
    let corrupt = |offset: u64, what: String| FormatError::Corrupt {
        path: path.to_path_buf(),
        offset,
        what,
    };
    let mut magic = [0u8; 14];
    let got = read_full(r, &mut magic, path, 0)?;
    if got == 0 {
        return Err(FormatError::Empty {
            path: path.to_path_buf(),
        });
    }
    if got < magic.len() || &magic != MAGIC {
        return Err(FormatError::Header {
            path: path.to_path_buf(),
            what: format!(
                "the file starts with {:?}, not the AEDAT 4 magic {:?}",
                String::from_utf8_lossy(&magic[..got]),
                String::from_utf8_lossy(MAGIC)
            ),
        });
    }
    let mut len = [0u8; 4];
    if read_full(r, &mut len, path, 14)? < 4 {
        return Err(FormatError::Truncated {
            path: path.to_path_buf(),
            offset: 14,
            what: "the IOHeader's length is missing".into(),
        });
    }
    let len = u32::from_le_bytes(len) as usize;
    if len > MAX_HEADER_BYTES {
        return Err(corrupt(
            14,
            format!(
                "IOHeader length {len} bytes is over the {MAX_HEADER_BYTES}-byte limit \
                 (aedat4::MAX_HEADER_BYTES)"
            ),
        ));
    }
    if let Some(file_len) = file_len
        && 18 + len as u64 > file_len
    {
        return Err(FormatError::Truncated {
            path: path.to_path_buf(),
            offset: 14,
            what: format!(
                "IOHeader length {len} bytes, but {} bytes follow in the {file_len}-byte file",
                file_len.saturating_sub(18)
            ),
        });
    }
    let mut buf = Vec::new();
    let got = read_up_to(r, len as u64, &mut buf, path, 18)?;
    if got < len {
        return Err(FormatError::Truncated {
            path: path.to_path_buf(),
            offset: 18 + got as u64,
            what: format!("{got} of the IOHeader's {len} bytes"),
        });
    }
    let bad = |what: &str| corrupt(18, format!("IOHeader: {what}"));
    if buf.get(4..8) != Some(b"IOHE") {
        return Err(bad("no `IOHE` identifier"));
    }
    let table = fb::Table::root(&buf).ok_or_else(|| bad("the root table lies outside it"))?;
    let code = table
        .i32(0, 0)
        .map_err(|()| bad("compression runs past the header"))?;
    let compression = Compression::from_code(code)
        .ok_or_else(|| bad(&format!("compression code {code} (0 to 4 are defined)")))?;
    let table_pos = table
        .i64(1, -1)
        .map_err(|()| bad("dataTablePosition runs past the header"))?;
    let description = table
        .str(2)
        .map_err(|()| bad("the description runs past the header or is not UTF-8"))?
        .ok_or_else(|| bad("no stream description"))?;
    let streams = parse_description(description).map_err(|what| bad(&what))?;
    let data_offset = 18 + len as u64;
    let data_table_position = match table_pos {
        p if p < 0 => None,
        p if (p as u64) < data_offset => {
            return Err(bad(&format!(
                "dataTablePosition {p} lies inside the header (packets start at byte {data_offset})"
            )));
        }
        p => Some(p as u64),
    };
    Ok(Aedat4Header {
        compression,
        data_table_position,
        streams,
        data_offset,
    })
}

/// The streams of DV's XML description: `<dv><node name="outInfo"><node name="ID">` with
/// `<attr key="typeIdentifier">` and `<node name="info">` holding `sizeX` and `sizeY`.
fn parse_description(xml: &str) -> std::result::Result<Vec<StreamInfo>, String> {
    let doc = roxmltree::Document::parse(xml).map_err(|e| format!("description XML: {e}"))?;
    let is_node = |n: &roxmltree::Node, name: &str| {
        n.is_element() && n.has_tag_name("node") && n.attribute("name") == Some(name)
    };
    let attr = |n: &roxmltree::Node, key: &str| {
        n.children()
            .find(|c| c.is_element() && c.has_tag_name("attr") && c.attribute("key") == Some(key))
            .and_then(|c| c.text())
            .map(str::trim)
            .map(str::to_string)
    };
    let out = doc
        .root_element()
        .children()
        .find(|n| is_node(n, "outInfo"))
        .ok_or("the description has no `outInfo` node")?;
    let mut streams: Vec<StreamInfo> = Vec::new();
    for node in out
        .children()
        .filter(|n| n.is_element() && n.has_tag_name("node"))
    {
        let name = node.attribute("name").unwrap_or("");
        let id: i32 = name
            .parse()
            .map_err(|_| format!("stream node name `{name}` is not an integer id"))?;
        let kind = attr(&node, "typeIdentifier")
            .ok_or_else(|| format!("stream {id} has no typeIdentifier"))?;
        let resolution = match node.children().find(|n| is_node(n, "info")) {
            Some(info) => match (attr(&info, "sizeX"), attr(&info, "sizeY")) {
                (Some(x), Some(y)) => {
                    let w: u16 = x
                        .parse()
                        .map_err(|_| format!("stream {id}: sizeX `{x}` is not a size"))?;
                    let h: u16 = y
                        .parse()
                        .map_err(|_| format!("stream {id}: sizeY `{y}` is not a size"))?;
                    Some(Resolution::new(w, h))
                }
                _ => None,
            },
            None => None,
        };
        if streams.iter().any(|s| s.id == id) {
            return Err(format!("stream id {id} is declared twice"));
        }
        streams.push(StreamInfo {
            id,
            kind,
            resolution,
        });
    }
    if streams.is_empty() {
        return Err("the description declares no stream".into());
    }
    Ok(streams)
}

/// Reads until `buf` is full or the source ends; returns the bytes read. An I/O error names the
/// offset of the read that began at `offset`.
fn read_full<R: Read>(r: &mut R, buf: &mut [u8], path: &Path, offset: u64) -> Result<usize> {
    crate::header::read_full(r, buf).map_err(|source| FormatError::Io {
        path: path.to_path_buf(),
        offset,
        source,
    })
}

/// Reads up to `n` bytes of `r` into `out` (cleared first) and returns how many came. `out` grows
/// with the bytes read, never to what `n` claims: a forged length costs no memory. An I/O error
/// names `offset`, where the read began.
fn read_up_to<R: Read>(
    r: &mut R,
    n: u64,
    out: &mut Vec<u8>,
    path: &Path,
    offset: u64,
) -> Result<usize> {
    out.clear();
    r.take(n)
        .read_to_end(out)
        .map_err(|source| FormatError::Io {
            path: path.to_path_buf(),
            offset,
            source,
        })
}

/// The size of `file`, when the system says.
fn file_len(file: &File) -> Option<u64> {
    file.metadata().ok().map(|m| m.len())
}

/// Packets in file order, decompressed on demand.
struct Packets<R> {
    src: R,
    path: PathBuf,
    header: Aedat4Header,
    /// The file's size, when known: a packet claiming more than is left is refused unread.
    file_len: Option<u64>,
    /// The most bytes a packet may take, stored or decompressed.
    max_bytes: usize,
    /// File offset of the next packet header.
    offset: u64,
    /// The stored bytes of the current packet.
    stored: Vec<u8>,
    /// Its payload, decompressed.
    payload: Vec<u8>,
    done: bool,
}

/// A packet just read: its stream, kind and file offset.
struct PacketRef {
    stream: i32,
    kind_index: usize,
    offset: u64,
}

impl<R: Read> Packets<R> {
    /// The next packet's header and stored bytes, or `None` at the end (EOF, or the packet index).
    /// With `want` false for a stream, its bytes are skipped without decompression.
    fn next(&mut self, want: impl Fn(i32) -> bool) -> Result<Option<PacketRef>> {
        if self.done {
            return Ok(None);
        }
        if self.header.data_table_position == Some(self.offset) {
            self.done = true;
            return Ok(None);
        }
        let at = self.offset;
        let mut head = [0u8; 8];
        let got = read_full(&mut self.src, &mut head, &self.path, at)?;
        if got == 0 && self.header.data_table_position.is_none() {
            self.done = true;
            return Ok(None);
        }
        let truncated = |offset: u64, what: String| FormatError::Truncated {
            path: self.path.clone(),
            offset,
            what,
        };
        if got < 8 {
            self.done = true;
            return Err(truncated(
                at,
                match self.header.data_table_position {
                    Some(p) if got == 0 => {
                        format!("the file ends before its packet index at byte {p}")
                    }
                    _ => format!("{got} of a packet header's 8 bytes"),
                },
            ));
        }
        let stream = i32::from_le_bytes([head[0], head[1], head[2], head[3]]);
        let size = u32::from_le_bytes([head[4], head[5], head[6], head[7]]) as usize;
        let corrupt = |what: String| FormatError::Corrupt {
            path: self.path.clone(),
            offset: at,
            what,
        };
        let Some(kind_index) = self.header.streams.iter().position(|s| s.id == stream) else {
            self.done = true;
            return Err(corrupt(format!(
                "packet of stream {stream}, which the description does not declare (declared: {})",
                self.header
                    .streams
                    .iter()
                    .map(|s| format!("{} {}", s.id, s.kind))
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        };
        if size > self.max_bytes {
            self.done = true;
            return Err(corrupt(format!(
                "packet of stream {stream}: size {size} bytes is over the {}-byte limit \
                 (aedat4::MAX_PACKET_BYTES; ReadOptions::max_packet_bytes raises it)",
                self.max_bytes
            )));
        }
        if let Some(len) = self.file_len
            && at + 8 + size as u64 > len
        {
            self.done = true;
            return Err(truncated(
                at,
                format!(
                    "packet of stream {stream}: size {size} bytes, but {} bytes follow its \
                     header in the {len}-byte file",
                    len.saturating_sub(at + 8)
                ),
            ));
        }
        if let Some(end) = self.header.data_table_position
            && at + 8 + size as u64 > end
        {
            self.done = true;
            return Err(corrupt(format!(
                "a {size}-byte packet runs past the packet index at byte {end}"
            )));
        }
        let got = if want(stream) {
            if self.file_len.is_some() {
                // Checked against the file's length above: the bytes are there, taken at once.
                self.stored.clear();
                self.stored.reserve_exact(size);
            }
            read_up_to(
                &mut self.src,
                size as u64,
                &mut self.stored,
                &self.path,
                at + 8,
            )?
        } else {
            let copied =
                std::io::copy(&mut (&mut self.src).take(size as u64), &mut std::io::sink())
                    .map_err(|source| FormatError::Io {
                        path: self.path.clone(),
                        offset: at + 8,
                        source,
                    })?;
            self.stored.clear();
            copied as usize
        };
        if got < size {
            self.done = true;
            return Err(truncated(
                at + 8 + got as u64,
                format!("{got} of packet {stream}'s {size} bytes (packet at byte {at})"),
            ));
        }
        self.offset = at + 8 + size as u64;
        Ok(Some(PacketRef {
            stream,
            kind_index,
            offset: at,
        }))
    }

    /// Decompresses the packet just read into `payload` and checks its size prefix and
    /// identifier; returns the FlatBuffer (after the prefix).
    fn open(&mut self, p: &PacketRef) -> Result<&[u8]> {
        let corrupt = |what: String| FormatError::Corrupt {
            path: self.path.clone(),
            offset: p.offset,
            what,
        };
        self.payload.clear();
        let decoded = match self.header.compression {
            Compression::None => {
                std::mem::swap(&mut self.stored, &mut self.payload);
                Ok(())
            }
            Compression::Lz4 => bounded_read(
                lz4_flex::frame::FrameDecoder::new(&self.stored[..]),
                &mut self.payload,
                self.max_bytes,
            ),
            Compression::Zstd => match zstd_window(&self.stored) {
                // The decoder reserves the window the frame asks for: refused before it does.
                Some(w) if w > self.max_bytes as u64 => Err(format!(
                    "its Zstandard frame asks for a {w}-byte window, over the {}-byte limit \
                     (aedat4::MAX_PACKET_BYTES; ReadOptions::max_packet_bytes raises it)",
                    self.max_bytes
                )),
                _ => match ruzstd::decoding::StreamingDecoder::new(&self.stored[..]) {
                    Ok(d) => bounded_read(d, &mut self.payload, self.max_bytes),
                    Err(e) => Err(e.to_string()),
                },
            },
        };
        decoded.map_err(|e| {
            corrupt(format!(
                "packet of stream {} does not decompress ({:?}): {e}",
                p.stream, self.header.compression
            ))
        })?;
        let b = &self.payload;
        let kind = &self.header.streams[p.kind_index].kind;
        let prefix = fb::u32_at(b, 0).ok_or_else(|| {
            corrupt(format!(
                "packet of stream {} holds {} bytes",
                p.stream,
                b.len()
            ))
        })? as usize;
        if prefix != b.len() - 4 {
            return Err(corrupt(format!(
                "packet of stream {}: size prefix {prefix} for {} bytes of FlatBuffer",
                p.stream,
                b.len() - 4
            )));
        }
        let buf = &b[4..];
        if buf.get(4..8) != Some(kind.as_bytes()) {
            return Err(corrupt(format!(
                "packet of stream {} ({kind}) carries identifier {:?}",
                p.stream,
                String::from_utf8_lossy(buf.get(4..8).unwrap_or(&[]))
            )));
        }
        Ok(buf)
    }
}

/// Reads `r` (a decompressor) into `out` through a reader that stops one byte past `max`: a
/// payload that expands to more is an error naming the limit, after at most `max + 1` bytes.
fn bounded_read(r: impl Read, out: &mut Vec<u8>, max: usize) -> std::result::Result<(), String> {
    let mut limited = r.take(max as u64 + 1);
    limited.read_to_end(out).map_err(|e| e.to_string())?;
    if out.len() > max {
        return Err(format!(
            "it decompresses to more than {max} bytes, the limit \
             (aedat4::MAX_PACKET_BYTES; ReadOptions::max_packet_bytes raises it)"
        ));
    }
    Ok(())
}

/// The window a Zstandard frame asks its decoder to hold (RFC 8878, 3.1.1.1: the window
/// descriptor, or the frame content size of a single-segment frame); `None` when `b` does not
/// start with a frame header (the decoder then says what is wrong).
fn zstd_window(b: &[u8]) -> Option<u64> {
    const ZSTD_MAGIC: u32 = 0xFD2F_B528;
    if fb::u32_at(b, 0)? != ZSTD_MAGIC {
        return None;
    }
    let descriptor = *b.get(4)?;
    if descriptor & 0x20 == 0 {
        // Window_Descriptor: exponent (5 bits) and mantissa (3 bits); at most 2^41 + 7 * 2^38.
        let w = *b.get(5)?;
        let base = 1u64 << (10 + u32::from(w >> 3));
        return Some(base + (base / 8) * u64::from(w & 7));
    }
    // Single segment: the window is the content size, after the dictionary id.
    let at = 5 + [0, 1, 2, 4][usize::from(descriptor & 3)];
    Some(match descriptor >> 6 {
        0 => u64::from(*b.get(at)?),
        1 => u64::from(fb::u16_at(b, at)?) + 256,
        2 => u64::from(fb::u32_at(b, at)?),
        _ => u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?),
    })
}

/// A streaming reader of the events of one `EVTS` stream (the first, unless chosen).
///
/// Packets of other streams are skipped unread and counted in
/// [`crate::ReadStats::skipped_packets`]. Timestamps are the file's µs times in ns, as recorded
/// (DV's clock is the Unix epoch in µs, about 1.6e15, far inside `i64` ns).
pub struct Aedat4Reader<R: Read> {
    packets: Packets<R>,
    stream: i32,
    current: Current,
    sink: Sink,
}

/// The event packet being delivered.
#[derive(Default)]
struct Current {
    /// Its events, and the next one to deliver.
    events: usize,
    next: usize,
    /// Where its first event lies in the payload.
    start: usize,
    /// Its file offset.
    offset: u64,
}

impl Aedat4Reader<BufReader<File>> {
    /// Opens an AEDAT 4 file and its first event stream. Sizes the file claims are also checked
    /// against its length.
    pub fn open(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<Self> {
        let path = path.as_ref();
        let file = crate::open_file(path)?;
        let len = file_len(&file);
        Self::with_len(
            BufReader::with_capacity(256 * 1024, file),
            path.to_path_buf(),
            opts,
            len,
        )
    }
}

impl<R: Read> Aedat4Reader<R> {
    /// Reads an AEDAT 4 stream from `r`, named `name` in errors.
    pub fn from_reader(r: R, name: impl Into<PathBuf>, opts: &ReadOptions) -> Result<Self> {
        Self::with_len(r, name.into(), opts, None)
    }

    /// [`Self::from_reader`] of a source of `file_len` bytes, when known.
    fn with_len(
        mut r: R,
        path: PathBuf,
        opts: &ReadOptions,
        file_len: Option<u64>,
    ) -> Result<Self> {
        let allow_unknown_size = opts.allow_unknown_size;
        let header = read_header(&mut r, &path, file_len)?;
        let Some(stream) = header.first("EVTS").cloned() else {
            return Err(FormatError::Unsupported {
                path,
                what: format!(
                    "no event (EVTS) stream; the file declares {}",
                    header
                        .streams
                        .iter()
                        .map(|s| format!("{} {}", s.id, s.kind))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        };
        let resolution = resolve_resolution(
            stream.resolution,
            opts.resolution,
            &path,
            allow_unknown_size,
            "the event stream's description has no sizeX and sizeY",
        )?;
        let offset = header.data_offset;
        Ok(Aedat4Reader {
            packets: Packets {
                src: r,
                path: path.clone(),
                header,
                file_len,
                max_bytes: opts.max_packet_bytes,
                offset,
                stored: Vec::new(),
                payload: Vec::new(),
                done: false,
            },
            stream: stream.id,
            current: Current::default(),
            sink: Sink::new(
                path,
                resolution.map_or(Bounds::Unknown, Bounds::Sensor),
                opts,
            ),
        })
    }

    /// What the file's start says.
    pub fn header(&self) -> &Aedat4Header {
        &self.packets.header
    }

    /// The sensor size, when the file or the options give one.
    pub(crate) fn known_resolution(&self) -> Option<Resolution> {
        self.sink.known
    }
}

/// Loads the next packet of event stream `stream` into `cur`, skipping (and counting in
/// `skipped`) other streams' packets and empty event packets; `false` at the end of the file.
fn load_events<R: Read>(
    packets: &mut Packets<R>,
    stream: i32,
    cur: &mut Current,
    skipped: &mut u64,
) -> Result<bool> {
    loop {
        let Some(p) = packets.next(|s| s == stream)? else {
            return Ok(false);
        };
        if p.stream != stream {
            *skipped += 1;
            continue;
        }
        let path = packets.path.clone();
        let buf = packets.open(&p)?;
        let corrupt = |what: &str| FormatError::Corrupt {
            path: path.clone(),
            offset: p.offset,
            what: format!("EventPacket: {what}"),
        };
        let table =
            fb::Table::root(buf).ok_or_else(|| corrupt("the root table lies outside it"))?;
        let (n, start) = match table.vector(0, EVENT_BYTES) {
            Ok(v) => v.unwrap_or((0, 0)),
            Err(()) => return Err(corrupt("the events vector runs past the packet")),
        };
        // Positions in the payload, which keeps the 4-byte size prefix in front.
        *cur = Current {
            events: n,
            next: 0,
            start: start + 4,
            offset: p.offset,
        };
        if n > 0 {
            return Ok(true);
        }
    }
}

impl<R: Read> EventReader for Aedat4Reader<R> {
    crate::events::sink_accessors!();

    fn read_into(&mut self, out: &mut EventBatch, max: usize) -> Result<usize> {
        let (packets, cur, stream) = (&mut self.packets, &mut self.current, self.stream);
        self.sink.read_with(out, max, |sink, out| {
            while !sink.full() {
                if cur.next == cur.events
                    && !load_events(packets, stream, cur, &mut sink.stats.skipped_packets)?
                {
                    sink.finish();
                    return Ok(());
                }
                let b = &packets.payload;
                // A block at a time, straight into `out`'s columns; when any of its events is
                // bad, or out of place, it is taken back and emitted event by event below.
                let k = (cur.events - cur.next).min(sink.room()).min(BLOCK_EVENTS);
                let at = cur.start + cur.next * EVENT_BYTES;
                let start = out.len();
                if decode_block(&b[at..at + k * EVENT_BYTES], out) && sink.accept_block(out, start)
                {
                    cur.next += k;
                    continue;
                }
                out.truncate(start);
                let block_end = cur.next + k;
                while cur.next < block_end && !sink.full() {
                    let i = cur.next;
                    let at = cur.start + i * EVENT_BYTES;
                    // In bounds: `load_events` checked the whole vector.
                    let e = &b[at..at + EVENT_BYTES];
                    let t_us = i64::from_le_bytes([e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7]]);
                    let x = i16::from_le_bytes([e[8], e[9]]);
                    let y = i16::from_le_bytes([e[10], e[11]]);
                    let on = e[12];
                    if on > 1 || x < 0 || y < 0 || t_us < 0 {
                        return Err(bad_event(&sink.path, cur.offset, i, t_us, x, y, on));
                    }
                    let t_ns = us_to_ns(t_us as u64, &sink.path, cur.offset)?;
                    cur.next += 1;
                    sink.emit(
                        out,
                        t_ns,
                        x as u32,
                        y as u32,
                        on == 1,
                        Location::Byte(cur.offset),
                    )?;
                }
            }
            Ok(())
        })
    }
}

/// Appends the `Event` structs of `records` to `out`'s columns (µs to ns, `on` to ±1); `false`
/// when one has a negative or overflowing time, a negative coordinate or a polarity byte other
/// than 0 or 1 (what was appended is then taken back by the caller). Branch-free per event.
fn decode_block(records: &[u8], out: &mut EventBatch) -> bool {
    /// Beyond this many µs, ns overflow `i64`.
    const MAX_US: u64 = (i64::MAX / 1000) as u64;
    let t_us = |e: &[u8]| i64::from_le_bytes([e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7]]);
    let recs = records.chunks_exact(EVENT_BYTES);
    // One pass per column (each vectorises), then one check over all of them: a negative time
    // is above MAX_US as u64, a negative coordinate above i16::MAX as u16.
    let bad = recs.clone().fold(false, |bad, e| {
        bad | (t_us(e) as u64 > MAX_US) | (e[9] & 0x80 != 0) | (e[11] & 0x80 != 0) | (e[12] > 1)
    });
    out.t_ns
        .extend(recs.clone().map(|e| t_us(e).wrapping_mul(1000)));
    out.x
        .extend(recs.clone().map(|e| u16::from_le_bytes([e[8], e[9]])));
    out.y
        .extend(recs.clone().map(|e| u16::from_le_bytes([e[10], e[11]])));
    out.polarity
        .extend(recs.map(|e| (e[12] as i8).wrapping_mul(2).wrapping_sub(1)));
    !bad
}

#[cold]
#[inline(never)]
fn bad_event(path: &Path, offset: u64, i: usize, t_us: i64, x: i16, y: i16, on: u8) -> FormatError {
    let what = if on > 1 {
        format!("event {i} of the packet: polarity byte {on} (a bool: 0 or 1)")
    } else if t_us < 0 {
        format!("event {i} of the packet: timestamp {t_us} us is negative")
    } else {
        format!("event {i} of the packet: coordinates ({x}, {y}) are negative")
    };
    FormatError::Corrupt {
        path: path.to_path_buf(),
        offset,
        what,
    }
}

/// An image format of an AEDAT 4 frame (OpenCV type codes, as DV stores them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameFormat {
    /// 8-bit grey (code 0).
    Gray,
    /// 16-bit grey, little-endian (code 2).
    Gray16,
    /// 8-bit BGR (code 16).
    Bgr,
    /// 8-bit BGRA (code 24).
    Bgra,
}

impl FrameFormat {
    fn from_code(code: i8) -> Option<Self> {
        match code {
            0 => Some(FrameFormat::Gray),
            2 => Some(FrameFormat::Gray16),
            16 => Some(FrameFormat::Bgr),
            24 => Some(FrameFormat::Bgra),
            _ => None,
        }
    }

    fn code(self) -> i8 {
        match self {
            FrameFormat::Gray => 0,
            FrameFormat::Gray16 => 2,
            FrameFormat::Bgr => 16,
            FrameFormat::Bgra => 24,
        }
    }

    /// Bytes per pixel.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            FrameFormat::Gray => 1,
            FrameFormat::Gray16 => 2,
            FrameFormat::Bgr => 3,
            FrameFormat::Bgra => 4,
        }
    }
}

/// One APS frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ApsFrame {
    /// The frame's timestamp (DV: the middle of the exposure), ns.
    pub t_ns: i64,
    /// Start and end of the exposure, ns (0 when the file does not say).
    pub exposure_begin_ns: i64,
    /// End of the exposure, ns.
    pub exposure_end_ns: i64,
    /// Pixel layout.
    pub format: FrameFormat,
    /// Columns.
    pub width: u16,
    /// Rows.
    pub height: u16,
    /// Row-major pixels, rows top-down, `width * height * format.bytes_per_pixel()` bytes.
    pub pixels: Vec<u8>,
}

impl ApsFrame {
    /// The frame as luminance in `[0, 1]`, row-major: grey / 255 (or / 65,535), colour through
    /// the BT.601 weights (0.299 R + 0.587 G + 0.114 B).
    pub fn luminance(&self) -> Vec<f32> {
        let p = &self.pixels;
        match self.format {
            FrameFormat::Gray => p.iter().map(|&v| f32::from(v) / 255.0).collect(),
            FrameFormat::Gray16 => p
                .chunks_exact(2)
                .map(|c| f32::from(u16::from_le_bytes([c[0], c[1]])) / 65_535.0)
                .collect(),
            FrameFormat::Bgr | FrameFormat::Bgra => p
                .chunks_exact(self.format.bytes_per_pixel())
                .map(|c| {
                    (0.114 * f32::from(c[0]) + 0.587 * f32::from(c[1]) + 0.299 * f32::from(c[2]))
                        / 255.0
                })
                .collect(),
        }
    }
}

/// The frames of one `FRME` stream (the first), in file order; packets of other streams are
/// skipped unread.
pub struct Aedat4Frames<R: Read> {
    packets: Packets<R>,
    stream: i32,
    failed: bool,
}

impl Aedat4Frames<BufReader<File>> {
    /// Opens an AEDAT 4 file for its frames. Sizes the file claims are also checked against its
    /// length.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let file = crate::open_file(path)?;
        let len = file_len(&file);
        Self::with_len(
            BufReader::with_capacity(256 * 1024, file),
            path.to_path_buf(),
            len,
        )
    }
}

impl<R: Read> Aedat4Frames<R> {
    /// Reads frames from `r`, named `name` in errors. A file without a frame stream gives none.
    pub fn from_reader(r: R, name: impl Into<PathBuf>) -> Result<Self> {
        Self::with_len(r, name.into(), None)
    }

    /// The most bytes one packet may take, stored or decompressed ([`MAX_PACKET_BYTES`] unless
    /// set here): raise it for frames larger than 64 MiB.
    pub fn with_max_packet_bytes(mut self, max: usize) -> Self {
        self.packets.max_bytes = max;
        self
    }

    /// [`Self::from_reader`] of a source of `file_len` bytes, when known.
    fn with_len(mut r: R, path: PathBuf, file_len: Option<u64>) -> Result<Self> {
        let header = read_header(&mut r, &path, file_len)?;
        let stream = header.first("FRME").map_or(i32::MIN, |s| s.id);
        let offset = header.data_offset;
        Ok(Aedat4Frames {
            packets: Packets {
                src: r,
                path,
                header,
                file_len,
                max_bytes: MAX_PACKET_BYTES,
                offset,
                stored: Vec::new(),
                payload: Vec::new(),
                done: false,
            },
            stream,
            failed: false,
        })
    }

    /// What the file's start says.
    pub fn header(&self) -> &Aedat4Header {
        &self.packets.header
    }

    fn next_frame(&mut self) -> Result<Option<ApsFrame>> {
        let stream = self.stream;
        loop {
            let Some(p) = self.packets.next(|s| s == stream)? else {
                return Ok(None);
            };
            if p.stream != stream {
                continue;
            }
            let path = self.packets.path.clone();
            let buf = self.packets.open(&p)?;
            let corrupt = |what: String| FormatError::Corrupt {
                path: path.clone(),
                offset: p.offset,
                what,
            };
            let t = fb::Table::root(buf)
                .ok_or_else(|| corrupt("Frame: the root table lies outside it".into()))?;
            let past = |field: &str| corrupt(format!("Frame: {field} runs past the packet"));
            let ns = |us: i64, field: &str| {
                us.checked_mul(1000)
                    .ok_or_else(|| corrupt(format!("Frame: {field} {us} us overflows i64 ns")))
            };
            let t_us = t.i64(0, 0).map_err(|()| past("t"))?;
            let exp_begin = t.i64(3, 0).map_err(|()| past("exposure begin"))?;
            let exp_end = t.i64(4, 0).map_err(|()| past("exposure end"))?;
            let code = t.i8(5, 0).map_err(|()| past("format"))?;
            let format = FrameFormat::from_code(code).ok_or_else(|| {
                corrupt(format!(
                    "Frame: format code {code} (0 grey, 2 grey16, 16 BGR, 24 BGRA are read)"
                ))
            })?;
            let w = t.i16(6, 0).map_err(|()| past("width"))?;
            let h = t.i16(7, 0).map_err(|()| past("height"))?;
            if w < 0 || h < 0 {
                return Err(corrupt(format!("Frame: size {w}x{h}")));
            }
            // At most 32,767^2 x 4 bytes: checked, for 32-bit targets.
            let want = (w as usize)
                .checked_mul(h as usize)
                .and_then(|n| n.checked_mul(format.bytes_per_pixel()))
                .ok_or_else(|| corrupt(format!("Frame: size {w}x{h} overflows usize")))?;
            let (n, start) = t
                .vector(10, 1)
                .map_err(|()| past("the pixel vector"))?
                .unwrap_or((0, 0));
            if n != want {
                return Err(corrupt(format!(
                    "Frame: {n} pixel bytes for a {w}x{h} {format:?} frame ({want} expected)"
                )));
            }
            return Ok(Some(ApsFrame {
                t_ns: ns(t_us, "t")?,
                exposure_begin_ns: ns(exp_begin, "exposure begin")?,
                exposure_end_ns: ns(exp_end, "exposure end")?,
                format,
                width: w as u16,
                height: h as u16,
                pixels: buf
                    .get(start..start + n)
                    .ok_or_else(|| past("the pixel vector"))?
                    .to_vec(),
            }));
        }
    }
}

impl<R: Read> Iterator for Aedat4Frames<R> {
    type Item = Result<ApsFrame>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        match self.next_frame() {
            Ok(f) => f.map(Ok),
            Err(e) => {
                self.failed = true;
                Some(Err(e))
            }
        }
    }
}

/// Writes an AEDAT 4 file: events as stream 0 (`EVTS`), frames as stream 1 (`FRME`), in packets
/// of up to [`EVENTS_PER_PACKET`] events, uncompressed or as LZ4 frames; no packet index.
///
/// Timestamps are floored to whole µs (counted in [`WriteSummary::floored_timestamps`]);
/// coordinates must fit DV's `i16`, events must come in time order.
pub struct Aedat4Writer<W: Write> {
    out: Out<W>,
    compression: Compression,
    resolution: Resolution,
    pending: Vec<[u8; EVENT_BYTES]>,
    last_t_ns: Option<i64>,
    summary: WriteSummary,
    /// Reused buffers: the FlatBuffer, and its compressed form.
    buf: Vec<u8>,
}

impl<W: Write> Aedat4Writer<W> {
    /// Starts a file: magic, `IOHeader` and the description of the two streams.
    ///
    /// # Errors
    /// [`FormatError::Unwritable`] for Zstd (not written) or a sensor wider or taller than
    /// `i16::MAX`; [`FormatError::Io`] when the sink fails.
    pub fn new(
        w: W,
        name: impl Into<PathBuf>,
        resolution: Resolution,
        compression: Compression,
    ) -> Result<Self> {
        let path = name.into();
        let unwritable = |what: String| FormatError::Unwritable {
            path: path.clone(),
            index: 0,
            what,
        };
        if compression == Compression::Zstd {
            return Err(unwritable(
                "Zstandard is read but not written; use None or Lz4".into(),
            ));
        }
        if resolution.width > i16::MAX as u16 || resolution.height > i16::MAX as u16 {
            return Err(unwritable(format!(
                "a {resolution} sensor does not fit AEDAT 4's 16-bit signed coordinates"
            )));
        }
        let mut me = Aedat4Writer {
            out: Out::new(w, path),
            compression,
            resolution,
            pending: Vec::with_capacity(EVENTS_PER_PACKET),
            last_t_ns: None,
            summary: WriteSummary::default(),
            buf: Vec::new(),
        };
        let header = io_header(compression, &description(resolution, compression));
        let mut start = Vec::with_capacity(18 + header.len());
        start.extend_from_slice(MAGIC);
        start.extend_from_slice(&(header.len() as u32).to_le_bytes());
        start.extend_from_slice(&header);
        me.out.put(&start)?;
        Ok(me)
    }

    /// Writes one packet whose FlatBuffer (size prefix included) is in `self.buf`.
    fn packet(&mut self, stream: i32) -> Result<()> {
        let body = match self.compression {
            Compression::Lz4 => {
                // With a content checksum, so damage to our files is caught on reading (DV's
                // own LZ4 and Zstd packets carry none).
                let mut info = lz4_flex::frame::FrameInfo::new();
                info.content_checksum = true;
                let mut enc = lz4_flex::frame::FrameEncoder::with_frame_info(info, Vec::new());
                let io = |source| FormatError::Io {
                    path: self.out.path.clone(),
                    offset: self.out.position(),
                    source,
                };
                enc.write_all(&self.buf).map_err(io)?;
                enc.finish()
                    .map_err(|e| io(std::io::Error::other(e.to_string())))?
            }
            _ => std::mem::take(&mut self.buf),
        };
        let mut head = [0u8; 8];
        head[..4].copy_from_slice(&stream.to_le_bytes());
        head[4..].copy_from_slice(&(body.len() as u32).to_le_bytes());
        self.out.put(&head)?;
        self.out.put(&body)?;
        self.buf = body;
        self.buf.clear();
        Ok(())
    }

    /// Writes the pending events as one packet.
    fn flush_events(&mut self) -> Result<()> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let n = self.pending.len();
        // Size prefix, root offset 16, `EVTS`, vtable (6 bytes: one field at 4) + 2 padding,
        // table (soffset, offset to the vector), vector length, then the 8-aligned events.
        let b = &mut self.buf;
        b.clear();
        b.extend_from_slice(&((28 + n * EVENT_BYTES) as u32).to_le_bytes());
        b.extend_from_slice(&16u32.to_le_bytes()); // root table at 16
        b.extend_from_slice(b"EVTS");
        b.extend_from_slice(&[6, 0, 8, 0, 4, 0, 0, 0]); // vtable at 8: 6 bytes, table 8 bytes, field 0 at +4
        b.extend_from_slice(&8i32.to_le_bytes()); // table at 16: vtable at 16 - 8
        b.extend_from_slice(&4u32.to_le_bytes()); // the vector at 20 + 4 = 24
        b.extend_from_slice(&(n as u32).to_le_bytes()); // at 24; elements at 28 (32 with prefix)
        for e in &self.pending {
            b.extend_from_slice(e);
        }
        self.pending.clear();
        self.packet(0)
    }

    /// Appends one frame as a packet of the frame stream (pending events are written first).
    ///
    /// # Errors
    /// [`FormatError::Unwritable`] when the pixel count does not match the size and format, or a
    /// timestamp is negative.
    pub fn write_frame(&mut self, f: &ApsFrame) -> Result<()> {
        self.flush_events()?;
        let index = self.summary.items;
        let unwritable = |what: String| self.out.unwritable(index, what);
        let want = usize::from(f.width) * usize::from(f.height) * f.format.bytes_per_pixel();
        if f.pixels.len() != want || f.width > i16::MAX as u16 || f.height > i16::MAX as u16 {
            return Err(unwritable(format!(
                "frame of {}x{} {:?} with {} pixel bytes ({want} expected)",
                f.width,
                f.height,
                f.format,
                f.pixels.len()
            )));
        }
        let us = |t: i64| ns_to_us(&self.out, index, t).map(|(t_us, _)| t_us as i64);
        let (t, b0, b1) = (
            us(f.t_ns)?,
            us(f.exposure_begin_ns)?,
            us(f.exposure_end_ns)?,
        );
        // Table at 16: soffset, then t, begin_t, end_t, exposure begin, exposure end (5 x i64
        // at 24..64), width, height, offset x, offset y (4 x i16 at 64..72), format (i8 at 72) and
        // 3 bytes of padding, the pixel vector's offset (u32 at 76); vtable at 8 ... the vtable is
        // 4 + 11 * 2 = 26 bytes, so it goes first, at 4 + 4 = 8, then the table at 36 (8-aligned
        // with the prefix: 40).
        let n = f.pixels.len();
        let b = &mut self.buf;
        b.clear();
        b.extend_from_slice(&[0; 4]); // size prefix, set below
        b.extend_from_slice(&36u32.to_le_bytes()); // root table
        b.extend_from_slice(b"FRME");
        // vtable at 8: size 26, table size 64; fields 0..=10.
        let table = 36usize;
        let fields: [u16; 11] = [8, 16, 24, 32, 40, 56, 48, 50, 52, 54, 60];
        b.extend_from_slice(&26u16.to_le_bytes());
        b.extend_from_slice(&64u16.to_le_bytes());
        for off in fields {
            b.extend_from_slice(&off.to_le_bytes());
        }
        b.extend_from_slice(&[0; 2]); // to 36
        b.extend_from_slice(&((table - 8) as i32).to_le_bytes()); // soffset: vtable at 8
        b.extend_from_slice(&[0; 4]); // to table + 8 (48 with the prefix: 8-aligned)
        for v in [t, t, t, b0, b1] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        for v in [f.width as i16, f.height as i16, 0, 0] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.push(f.format.code() as u8); // table + 56
        b.extend_from_slice(&[0; 3]);
        // table + 60: offset to the vector, which follows at table + 64.
        b.extend_from_slice(&4u32.to_le_bytes());
        b.extend_from_slice(&(n as u32).to_le_bytes());
        b.extend_from_slice(&f.pixels);
        let len = (b.len() - 4) as u32;
        b[..4].copy_from_slice(&len.to_le_bytes());
        self.packet(1)
    }

    /// Flushes the last packet and returns the sink and what was written.
    pub fn finish(mut self) -> Result<(W, WriteSummary)> {
        self.flush_events()?;
        self.out.finish_with(self.summary)
    }
}

impl<W: Write> crate::EventWriter for Aedat4Writer<W> {
    fn write_event(&mut self, e: &Event) -> Result<()> {
        let index = self.summary.items;
        let unwritable = |what: String| self.out.unwritable(index, what);
        if e.x >= self.resolution.width || e.y >= self.resolution.height {
            return Err(unwritable(format!(
                "({}, {}) is outside the {} sensor",
                e.x, e.y, self.resolution
            )));
        }
        if let Some(last) = self.last_t_ns
            && e.t_ns < last
        {
            return Err(unwritable(format!(
                "timestamp {} ns comes after {last} ns",
                e.t_ns
            )));
        }
        if e.polarity != 1 && e.polarity != -1 {
            return Err(unwritable(format!("polarity {} is not ±1", e.polarity)));
        }
        let (t_us, floored) = ns_to_us(&self.out, index, e.t_ns)?;
        self.last_t_ns = Some(e.t_ns);
        self.summary.floored_timestamps += u64::from(floored);
        self.summary.items += 1;
        let mut rec = [0u8; EVENT_BYTES];
        rec[..8].copy_from_slice(&(t_us as i64).to_le_bytes());
        rec[8..10].copy_from_slice(&(e.x as i16).to_le_bytes());
        rec[10..12].copy_from_slice(&(e.y as i16).to_le_bytes());
        rec[12] = u8::from(e.polarity > 0);
        self.pending.push(rec);
        if self.pending.len() == EVENTS_PER_PACKET {
            self.flush_events()?;
        }
        Ok(())
    }
}

/// The XML description of the writer's two streams.
fn description(r: Resolution, compression: Compression) -> String {
    let c = match compression {
        Compression::None => "NONE",
        Compression::Lz4 => "LZ4",
        Compression::Zstd => "ZSTD",
    };
    let stream = |id: u32, output: &str, kind: &str| {
        format!(
            "        <node name=\"{id}\" path=\"/outInfo/{id}/\">\n\
             \x20           <attr key=\"compression\" type=\"string\">{c}</attr>\n\
             \x20           <attr key=\"originalModuleName\" type=\"string\">neuspike</attr>\n\
             \x20           <attr key=\"originalOutputName\" type=\"string\">{output}</attr>\n\
             \x20           <attr key=\"typeDescription\" type=\"string\">Custom data type output.</attr>\n\
             \x20           <attr key=\"typeIdentifier\" type=\"string\">{kind}</attr>\n\
             \x20           <node name=\"info\" path=\"/outInfo/{id}/info/\">\n\
             \x20               <attr key=\"sizeX\" type=\"int\">{w}</attr>\n\
             \x20               <attr key=\"sizeY\" type=\"int\">{h}</attr>\n\
             \x20               <attr key=\"source\" type=\"string\">neuspike</attr>\n\
             \x20           </node>\n\
             \x20       </node>\n",
            w = r.width,
            h = r.height
        )
    };
    format!(
        "<dv version=\"2.0\">\n    <node name=\"outInfo\" path=\"/outInfo/\">\n{}{}    </node>\n</dv>\n",
        stream(0, "events", "EVTS"),
        stream(1, "frames", "FRME")
    )
}

/// The `IOHeader` FlatBuffer (no size prefix: the file's `u32` length stands before it).
fn io_header(compression: Compression, description: &str) -> Vec<u8> {
    // Root offset, `IOHE`, vtable at 8 (10 bytes: 3 fields) + 2 padding, table at 20:
    // soffset, compression (i32 at +4), then dataTablePosition (i64 at +8, 8-aligned at 28 +
    // ... kept 8-aligned relative to the buffer), the description's offset (u32 at +16); the
    // string follows.
    let mut b = Vec::with_capacity(48 + description.len());
    b.extend_from_slice(&24u32.to_le_bytes()); // root table at 24
    b.extend_from_slice(b"IOHE");
    b.extend_from_slice(&10u16.to_le_bytes()); // vtable at 8
    b.extend_from_slice(&24u16.to_le_bytes()); // table size
    b.extend_from_slice(&4u16.to_le_bytes()); // compression at +4
    b.extend_from_slice(&8u16.to_le_bytes()); // dataTablePosition at +8
    b.extend_from_slice(&16u16.to_le_bytes()); // description at +16
    b.extend_from_slice(&[0; 6]); // to 24
    b.extend_from_slice(&16i32.to_le_bytes()); // table at 24: vtable at 24 - 16 = 8
    b.extend_from_slice(&compression.code().to_le_bytes()); // 28
    b.extend_from_slice(&(-1i64).to_le_bytes()); // 32
    b.extend_from_slice(&8u32.to_le_bytes()); // 40: the string at 48
    b.extend_from_slice(&[0; 4]); // 44
    b.extend_from_slice(&(description.len() as u32).to_le_bytes()); // 48
    b.extend_from_slice(description.as_bytes());
    b.push(0);
    while b.len() % 4 != 0 {
        b.push(0);
    }
    b
}
