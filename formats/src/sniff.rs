//! Telling formats apart by content, never by file name: a `.dat` file may be PKU spike planes
//! (no header at all) or Prophesee DAT events (a `%` header, then a type/size byte pair).

use std::fmt;
use std::fs::File;
use std::io::Cursor;
use std::path::Path;

use crate::dat::{RECORD_BYTES, is_type_size_pair};
use crate::error::{FormatError, Result};
use crate::header::{EvtVersion, read_header, read_some};

/// Bytes [`sniff`] reads from the start of a file.
pub const SNIFF_BYTES: usize = 64 * 1024;
const AEDAT4_MAGIC: &[u8] = b"#!AER-DAT4";
const HDF5_MAGIC: &[u8] = b"\x89HDF\r\n\x1a\n";

/// A recording format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Format {
    /// PKU spike-camera planes ([`crate::pku`]): binary without any header.
    PkuSpikes,
    /// Event Camera Dataset text ([`crate::text`]).
    EventText,
    /// Prophesee RAW ([`crate::raw`]) in the named encoding.
    PropheseeRaw(EvtVersion),
    /// Prophesee DAT events ([`crate::dat`]).
    PropheseeDat,
    /// AEDAT 4 ([`crate::aedat4`]), by its `#!AER-DAT4` magic.
    Aedat4,
    /// HDF5 (recognised by its signature; not decoded).
    Hdf5,
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Format::PkuSpikes => f.write_str("PKU spike planes"),
            Format::EventText => f.write_str("Event Camera Dataset text"),
            Format::PropheseeRaw(v) => write!(f, "Prophesee RAW {v}"),
            Format::PropheseeDat => f.write_str("Prophesee DAT events"),
            Format::Aedat4 => f.write_str("AEDAT 4"),
            Format::Hdf5 => f.write_str("HDF5"),
        }
    }
}

/// The format of the file at `path`, from its first [`SNIFF_BYTES`] bytes and its size.
pub fn sniff(path: impl AsRef<Path>) -> Result<Format> {
    let path = path.as_ref();
    let open_err = |source| FormatError::Open {
        path: path.to_path_buf(),
        source,
    };
    let mut file = File::open(path).map_err(open_err)?;
    let len = file.metadata().map_err(open_err)?.len();
    let mut prefix = vec![0u8; SNIFF_BYTES];
    let mut got = 0;
    while got < prefix.len() {
        let n = read_some(&mut file, &mut prefix[got..]).map_err(|source| FormatError::Io {
            path: path.to_path_buf(),
            offset: got as u64,
            source,
        })?;
        if n == 0 {
            break;
        }
        got += n;
    }
    prefix.truncate(got);
    sniff_bytes(&prefix, len, path)
}

/// The format of a file of `len` bytes that starts with `prefix`.
///
/// * `#!AER-DAT4` -> AEDAT 4; the HDF5 signature -> HDF5.
/// * a `%` header that names an EVT encoding -> Prophesee RAW;
/// * a `%` header followed by a DAT type/size pair (or naming DAT contents or version) -> DAT;
/// * any other `%` header -> an [`FormatError::Ambiguous`] error that says what was seen;
/// * printable text whose first line is an event line or a `width height` line -> text (other
///   text is an error);
/// * binary without a header -> PKU spike planes, the one headerless format.
pub fn sniff_bytes(prefix: &[u8], len: u64, path: &Path) -> Result<Format> {
    let ambiguous = |what: String| FormatError::Ambiguous {
        path: path.to_path_buf(),
        what,
    };
    if len == 0 || prefix.is_empty() {
        return Err(FormatError::Empty {
            path: path.to_path_buf(),
        });
    }
    if prefix.starts_with(AEDAT4_MAGIC) {
        return Ok(Format::Aedat4);
    }
    if prefix.starts_with(HDF5_MAGIC) {
        return Ok(Format::Hdf5);
    }
    if prefix[0] == b'%' {
        let (h, rest) = read_header(&mut Cursor::new(prefix), path)?;
        if !h.lines.is_empty() || h.explicit_end {
            if let Some(v) = h.evt {
                return Ok(Format::PropheseeRaw(v));
            }
            if h.dat_contents.is_some() || h.dat_version.is_some() {
                return Ok(Format::PropheseeDat);
            }
            // Bytes after the header: at least those read (a file that grew since its size was
            // taken, or a `len` smaller than the prefix, must not underflow the subtraction).
            let after = len.max(prefix.len() as u64).saturating_sub(h.data_offset);
            if rest.len() >= 2
                && is_type_size_pair(rest[0], rest[1])
                && after
                    .checked_sub(2)
                    .is_some_and(|records| records % RECORD_BYTES as u64 == 0)
            {
                return Ok(Format::PropheseeDat);
            }
            let pair = match rest.get(..2) {
                Some(p) => format!("bytes {:#04x} {:#04x}", p[0], p[1]),
                None => format!("{} byte(s)", rest.len()),
            };
            return Err(ambiguous(format!(
                "a {}-line `%` header ({} bytes) names no RAW encoding (`% evt`, `% format`) and no \
                 DAT contents or version, and the {pair} after it at byte {} are not a DAT event \
                 type/size pair followed by whole 8-byte records ({after} bytes after the header); \
                 neither Prophesee RAW, Prophesee DAT nor PKU spikes (which have no header)",
                h.lines.len(),
                h.data_offset,
                h.data_offset,
            )));
        }
    }
    if looks_like_text(prefix) {
        let first = prefix
            .split(|&b| b == b'\n')
            .map(<[u8]>::trim_ascii)
            .find(|l| !l.is_empty() && l[0] != b'#')
            .unwrap_or(&[]);
        let n_fields = first
            .split(u8::is_ascii_whitespace)
            .filter(|f| !f.is_empty())
            .count();
        let numeric = first
            .iter()
            .all(|&b| b.is_ascii_digit() || b == b'.' || b.is_ascii_whitespace());
        if numeric && (n_fields == 4 || n_fields == 2) {
            return Ok(Format::EventText);
        }
        return Err(ambiguous(format!(
            "text whose first line `{}` is neither `t_seconds x y polarity` nor `width height`",
            String::from_utf8_lossy(&first[..first.len().min(80)])
        )));
    }
    Ok(Format::PkuSpikes)
}

fn looks_like_text(prefix: &[u8]) -> bool {
    prefix
        .iter()
        .all(|&b| (0x20..0x7f).contains(&b) || matches!(b, b'\n' | b'\r' | b'\t'))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sniff_mem(bytes: &[u8]) -> Result<Format> {
        sniff_bytes(bytes, bytes.len() as u64, Path::new("x.dat"))
    }

    #[test]
    fn each_format_by_content() {
        assert_eq!(
            sniff_mem(b"% evt 3.0\n\x00\x80").unwrap(),
            Format::PropheseeRaw(EvtVersion::Evt3)
        );
        assert_eq!(
            sniff_mem(b"% Date 2020\n\x0c\x08\x01\x00\x00\x00\x00\x00\x00\x00").unwrap(),
            Format::PropheseeDat
        );
        assert_eq!(
            sniff_mem(b"240 180\n0.5 1 2 1\n").unwrap(),
            Format::EventText
        );
        assert_eq!(sniff_mem(b"0.5 1 2 1\n").unwrap(), Format::EventText);
        assert_eq!(
            sniff_mem(&[0x00, 0xff, 0x10, 0x25]).unwrap(),
            Format::PkuSpikes
        );
        // A spike file whose first byte happens to be '%' but is not followed by a text line.
        assert_eq!(
            sniff_mem(&[b'%', 0x00, 0xff, b'\n']).unwrap(),
            Format::PkuSpikes
        );
        assert_eq!(sniff_mem(b"#!AER-DAT4.0\r\n").unwrap(), Format::Aedat4);
    }

    #[test]
    fn header_without_a_known_continuation_is_ambiguous() {
        let e = sniff_mem(b"% just a note\n\x01\x02\x03")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("x.dat") && e.contains("0x01 0x02") && e.contains("byte 14"),
            "{e}"
        );
        let e = sniff_mem(b"hello world\n").unwrap_err().to_string();
        assert!(e.contains("hello world"), "{e}");
        assert!(matches!(sniff_mem(b""), Err(FormatError::Empty { .. })));
    }

    /// A size smaller than the bytes read (a file that grew after its size was taken, or a
    /// caller's wrong `len`) used to underflow `after - 2` (a panic in debug builds, a wrapped
    /// count in release ones): the bytes read count, and whole records after the pair are DAT.
    #[test]
    fn a_size_smaller_than_the_prefix_does_not_underflow() {
        let bytes = b"% x\n\x0c\x08";
        for len in 1..bytes.len() as u64 {
            assert_eq!(
                sniff_bytes(bytes, len, Path::new("x.dat")).unwrap(),
                Format::PropheseeDat,
                "len {len}"
            );
        }
        // A pair followed by a partial record is still not DAT, whatever `len` says.
        let e = sniff_bytes(b"% x\n\x0c\x08\x01", 5, Path::new("x.dat")).unwrap_err();
        assert!(matches!(e, FormatError::Ambiguous { .. }), "{e}");
    }
}
