//! The ASCII header of Prophesee files (RAW and DAT): lines `% key value` before the binary data.
//!
//! A line belongs to the header when it starts with `%` and holds only printable ASCII (and tabs)
//! up to its line feed; the header also ends at a `% end` line. A `%` byte followed by anything
//! else is the first byte of the binary data, which can legitimately be 0x25.

use std::io::{Cursor, Read};
use std::path::Path;

use crate::error::{FormatError, Result};
use crate::events::Resolution;

/// Longest header line accepted, in bytes.
pub const MAX_HEADER_LINE: usize = 64 * 1024;
/// Largest header accepted, in bytes.
pub const MAX_HEADER: usize = 1 << 20;
const READ_STEP: usize = 8 * 1024;

/// The encodings of Prophesee RAW files.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum EvtVersion {
    /// EVT 2.0: 32-bit words.
    Evt2,
    /// EVT 2.1: 64-bit vectorised words (recognised, not decoded).
    Evt21,
    /// EVT 3.0: 16-bit words.
    Evt3,
}

impl std::fmt::Display for EvtVersion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            EvtVersion::Evt2 => "EVT 2.0",
            EvtVersion::Evt21 => "EVT 2.1",
            EvtVersion::Evt3 => "EVT 3.0",
        })
    }
}

/// A parsed `%` header.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PropheseeHeader {
    /// Each header line without its `%`, leading spaces and line end.
    pub lines: Vec<String>,
    /// Header length in bytes: the binary data starts here.
    pub data_offset: u64,
    /// Sensor size, from `geometry WxH`, `format ...;width=W;height=H` or `Width`/`Height`.
    pub resolution: Option<Resolution>,
    /// RAW encoding, from `evt 2.0` or `format EVT2...`.
    pub evt: Option<EvtVersion>,
    /// DAT format version, from `Version N`.
    pub dat_version: Option<u32>,
    /// Whether the header names a DAT event kind (`Data file containing ...`).
    pub dat_contents: Option<String>,
    /// Whether the header ended with an explicit `% end` line.
    pub explicit_end: bool,
}

impl PropheseeHeader {
    /// The value of the first line whose key is `key` (case-sensitive).
    pub fn value(&self, key: &str) -> Option<&str> {
        self.lines.iter().find_map(|l| {
            let (k, v) = l.split_once(' ')?;
            (k == key).then_some(v.trim())
        })
    }
}

fn is_header_text(line: &[u8]) -> bool {
    line.iter()
        .all(|&b| (0x20..0x7f).contains(&b) || b == b'\t' || b == b'\r')
}

/// Reads the header from the start of `r`. Returns it and the bytes read past it (the first
/// bytes of the binary data), which the caller must consume before reading on from `r`.
pub fn read_header<R: Read>(r: &mut R, path: &Path) -> Result<(PropheseeHeader, Vec<u8>)> {
    let mut buf: Vec<u8> = Vec::new();
    let mut eof = false;
    let mut pos = 0usize;
    let mut h = PropheseeHeader::default();
    let fill = |buf: &mut Vec<u8>, eof: &mut bool, r: &mut R| -> Result<()> {
        let old = buf.len();
        buf.resize(old + READ_STEP, 0);
        let n = read_some(r, &mut buf[old..]).map_err(|source| FormatError::Io {
            path: path.to_path_buf(),
            offset: old as u64,
            source,
        })?;
        buf.truncate(old + n);
        *eof = n == 0;
        Ok(())
    };
    loop {
        while buf.len() <= pos && !eof {
            fill(&mut buf, &mut eof, r)?;
        }
        if buf.get(pos) != Some(&b'%') {
            break;
        }
        // Find the end of this line.
        let mut nl = buf[pos..].iter().position(|&b| b == b'\n');
        while nl.is_none() && !eof && buf.len() - pos <= MAX_HEADER_LINE {
            fill(&mut buf, &mut eof, r)?;
            nl = buf[pos..].iter().position(|&b| b == b'\n');
        }
        let (line_end, next) = match nl {
            Some(i) => (pos + i, pos + i + 1),
            // A last header line without a line feed, at the end of the file.
            None if eof => (buf.len(), buf.len()),
            None => break, // longer than any header line: binary data
        };
        let line = &buf[pos + 1..line_end];
        if !is_header_text(line) {
            break;
        }
        let text = String::from_utf8_lossy(line).trim().to_string();
        pos = next;
        if pos > MAX_HEADER {
            return Err(FormatError::Header {
                path: path.to_path_buf(),
                what: format!("longer than {MAX_HEADER} bytes"),
            });
        }
        if text == "end" {
            h.explicit_end = true;
            break;
        }
        parse_line(&mut h, &text, path)?;
        h.lines.push(text);
    }
    h.data_offset = pos as u64;
    let rest = buf.split_off(pos);
    Ok((h, rest))
}

/// `read` that retries on interruption.
pub(crate) fn read_some<R: Read>(r: &mut R, buf: &mut [u8]) -> std::io::Result<usize> {
    loop {
        match r.read(buf) {
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            other => return other,
        }
    }
}

/// Reads until `buf` is full or the source ends; returns the bytes read.
pub(crate) fn read_full<R: Read>(r: &mut R, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        let n = read_some(r, &mut buf[got..])?;
        if n == 0 {
            break;
        }
        got += n;
    }
    Ok(got)
}

fn parse_dim(s: &str) -> Option<u16> {
    s.trim().parse::<u16>().ok().filter(|&v| v > 0)
}

fn parse_line(h: &mut PropheseeHeader, text: &str, path: &Path) -> Result<()> {
    let bad = |what: String| FormatError::Header {
        path: path.to_path_buf(),
        what,
    };
    let (key, value) = match text.split_once([' ', '\t']) {
        Some((k, v)) => (k, v.trim()),
        None => (text, ""),
    };
    match key {
        "evt" => {
            h.evt = Some(match value {
                "2" | "2.0" => EvtVersion::Evt2,
                "2.1" => EvtVersion::Evt21,
                "3" | "3.0" => EvtVersion::Evt3,
                other => return Err(bad(format!("unknown `% evt {other}`"))),
            });
        }
        "format" => {
            let mut parts = value.split(';');
            let name = parts.next().unwrap_or("").trim();
            h.evt = Some(match name.to_ascii_uppercase().as_str() {
                "EVT2" | "EVT2.0" => EvtVersion::Evt2,
                "EVT21" | "EVT2.1" => EvtVersion::Evt21,
                "EVT3" | "EVT3.0" => EvtVersion::Evt3,
                _ => return Err(bad(format!("unknown format in `% format {value}`"))),
            });
            let (mut w, mut hh) = (None, None);
            for p in parts {
                if let Some((k, v)) = p.split_once('=') {
                    match k.trim() {
                        "width" => {
                            w =
                                Some(parse_dim(v).ok_or_else(|| {
                                    bad(format!("bad width in `% format {value}`"))
                                })?)
                        }
                        "height" => {
                            hh =
                                Some(parse_dim(v).ok_or_else(|| {
                                    bad(format!("bad height in `% format {value}`"))
                                })?)
                        }
                        _ => {}
                    }
                }
            }
            if let (Some(w), Some(hh)) = (w, hh) {
                set_resolution(h, Resolution::new(w, hh), text, path)?;
            }
        }
        "geometry" => {
            let (w, hh) = value
                .split_once('x')
                .and_then(|(w, hh)| Some((parse_dim(w)?, parse_dim(hh)?)))
                .ok_or_else(|| bad(format!("bad `% geometry {value}`, expected WIDTHxHEIGHT")))?;
            set_resolution(h, Resolution::new(w, hh), text, path)?;
        }
        "Width" | "Height" => {
            let v = parse_dim(value).ok_or_else(|| bad(format!("bad `% {key} {value}`")))?;
            let mut r = h.resolution.unwrap_or(Resolution::new(0, 0));
            if key == "Width" {
                r.width = v;
            } else {
                r.height = v;
            }
            h.resolution = Some(r);
        }
        "Version" => {
            h.dat_version = Some(
                value
                    .parse()
                    .map_err(|_| bad(format!("bad `% Version {value}`")))?,
            );
        }
        "Data" => {
            if let Some(what) = value.strip_prefix("file containing") {
                h.dat_contents = Some(what.trim().trim_end_matches('.').to_string());
            }
        }
        _ => {}
    }
    Ok(())
}

fn set_resolution(h: &mut PropheseeHeader, r: Resolution, text: &str, path: &Path) -> Result<()> {
    match h.resolution {
        Some(old) if old != r && old.width != 0 && old.height != 0 => Err(FormatError::Header {
            path: path.to_path_buf(),
            what: format!("`% {text}` says {r}, an earlier line said {old}"),
        }),
        _ => {
            h.resolution = Some(r);
            Ok(())
        }
    }
}

/// The sensor size to use: the header's, the options', or an error when they disagree or both
/// are missing. `Ok(None)` only when `allow_unknown`.
pub(crate) fn resolve_resolution(
    header: Option<Resolution>,
    option: Option<Resolution>,
    path: &Path,
    allow_unknown: bool,
    looked_in: &str,
) -> Result<Option<Resolution>> {
    let header = header.filter(|r| r.width > 0 && r.height > 0);
    match (header, option) {
        (Some(h), Some(o)) if h != o => Err(FormatError::Header {
            path: path.to_path_buf(),
            what: format!("the file says {h}, ReadOptions::resolution says {o}"),
        }),
        (Some(h), _) => Ok(Some(h)),
        (None, Some(o)) => Ok(Some(o)),
        (None, None) if allow_unknown => Ok(None),
        (None, None) => Err(FormatError::MissingResolution {
            path: path.to_path_buf(),
            what: looked_in.to_string(),
        }),
    }
}

/// The rest of a stream after its header: the bytes already read, then the reader.
pub(crate) type AfterHeader<R> = std::io::Chain<Cursor<Vec<u8>>, R>;

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(bytes: &[u8]) -> (PropheseeHeader, Vec<u8>) {
        read_header(&mut Cursor::new(bytes.to_vec()), Path::new("mem")).unwrap()
    }

    #[test]
    fn raw_header_with_format_line_and_end() {
        let (h, rest) = parse(b"% camera_integrator_name Prophesee\n% format EVT3;height=720;width=1280\n% geometry 1280x720\n% end\n\x01\x02");
        assert_eq!(h.evt, Some(EvtVersion::Evt3));
        assert_eq!(h.resolution, Some(Resolution::new(1280, 720)));
        assert!(h.explicit_end);
        assert_eq!(rest, vec![1, 2]);
        assert_eq!(h.value("camera_integrator_name"), Some("Prophesee"));
    }

    #[test]
    fn binary_starting_with_percent_is_data() {
        // 0x25 = '%', then a non-text byte before any line feed.
        let (h, rest) = parse(b"% evt 2.0\n%\x80\x00\x0a\x00");
        assert_eq!(h.evt, Some(EvtVersion::Evt2));
        assert_eq!(h.data_offset, 10);
        assert_eq!(rest, b"%\x80\x00\x0a\x00");
    }

    #[test]
    fn dat_header() {
        let (h, rest) = parse(
            b"% Data file containing CD events.\n% Version 2\n% Width 304\n% Height 240\n\x0c\x08",
        );
        assert_eq!(h.dat_contents.as_deref(), Some("CD events"));
        assert_eq!(h.dat_version, Some(2));
        assert_eq!(h.resolution, Some(Resolution::new(304, 240)));
        assert_eq!(rest, vec![0x0c, 0x08]);
    }

    #[test]
    fn contradicting_geometry_is_named() {
        let e = read_header(
            &mut Cursor::new(b"% format EVT2;height=480;width=640\n% geometry 320x320\n".to_vec()),
            Path::new("f.raw"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("f.raw") && e.contains("320x320") && e.contains("640x480"),
            "{e}"
        );
    }
}
