//! NumPy `.npy` frame stacks: float32 `[T, H, W]` intensities, read one frame at a time.
//!
//! What `neuspike frames-to-events` reads (v2e's job: video frames in, events out). The header
//! (format versions 1 to 3) is parsed for `descr`, `fortran_order` and `shape`; a C-order file
//! is then read frame by frame, so a video of any length takes two frames of memory. A
//! Fortran-order file (what `np.save` writes for a transposed array) has each frame spread over
//! the whole file: [`NpyFrames::fortran_order`] says so, and the caller reads it whole.
//!
//! Nothing is allocated from what the header claims beyond one frame, and only once the file's
//! size has been checked against the shape.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use crate::error::{FormatError, Result};

/// The longest header read: 1 MiB (NumPy writes a few hundred bytes; a longer claim is an error
/// naming this limit). The header's bytes are read as they come, never into a buffer sized by
/// the claimed length.
pub const MAX_HEADER_BYTES: usize = 1 << 20;

/// What an `.npy` header says.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NpyHeader {
    /// The element type, e.g. `<f4`.
    pub descr: String,
    /// Whether the data is in Fortran (column-major) order.
    pub fortran_order: bool,
    /// The array's shape.
    pub shape: Vec<usize>,
    /// Bytes before the data (magic, version, length and the header text).
    pub data_offset: u64,
}

/// Parses an `.npy` header from the first bytes of a file; `path` names it in errors.
///
/// # Errors
/// Not an `.npy` file, a version other than 1 to 3, a header longer than 1 MiB, or a header
/// without `descr`, `fortran_order` or `shape`.
pub fn parse_header(reader: &mut impl Read, path: &Path) -> Result<NpyHeader> {
    let bad = |what: String| FormatError::Header {
        path: path.to_path_buf(),
        what,
    };
    let mut lead = [0u8; 8];
    read_exact(reader, &mut lead, path, 0)?;
    if &lead[..6] != b"\x93NUMPY" {
        return Err(bad(format!("magic {:02x?}: not an .npy file", &lead[..6])));
    }
    let (len, width) = match lead[6] {
        1 => {
            let mut b = [0u8; 2];
            read_exact(reader, &mut b, path, 8)?;
            (usize::from(u16::from_le_bytes(b)), 2)
        }
        2 | 3 => {
            let mut b = [0u8; 4];
            read_exact(reader, &mut b, path, 8)?;
            (
                usize::try_from(u32::from_le_bytes(b)).unwrap_or(usize::MAX),
                4,
            )
        }
        v => {
            return Err(bad(format!(
                "version {v}.{}: only 1 to 3 are read",
                lead[7]
            )));
        }
    };
    if len > MAX_HEADER_BYTES {
        return Err(bad(format!(
            "header length {len} bytes: over the {MAX_HEADER_BYTES} read (npy::MAX_HEADER_BYTES)"
        )));
    }
    let mut text = Vec::new();
    let got = (&mut *reader)
        .take(len as u64)
        .read_to_end(&mut text)
        .map_err(|source| FormatError::Io {
            path: path.to_path_buf(),
            offset: (8 + width) as u64,
            source,
        })?;
    if got < len {
        return Err(FormatError::Truncated {
            path: path.to_path_buf(),
            offset: (8 + width + got) as u64,
            what: format!("header length {len} bytes, but the file ends after {got}"),
        });
    }
    let text = std::str::from_utf8(&text)
        .map_err(|e| bad(format!("header is not UTF-8: {e}")))?
        .trim_end_matches(['\n', ' ', '\0']);
    let dict = Dict::parse(text).map_err(|what| bad(format!("{what} in `{text}`")))?;
    let descr = dict
        .get("descr")
        .and_then(Value::as_str)
        .ok_or_else(|| bad(format!("no 'descr' string in `{text}`")))?
        .to_string();
    let fortran_order = dict
        .get("fortran_order")
        .and_then(Value::as_bool)
        .ok_or_else(|| bad(format!("no 'fortran_order' True/False in `{text}`")))?;
    let shape = dict
        .get("shape")
        .and_then(Value::as_tuple)
        .ok_or_else(|| bad(format!("no 'shape' tuple in `{text}`")))?
        .to_vec();
    Ok(NpyHeader {
        descr,
        fortran_order,
        shape,
        data_offset: (8 + width + len) as u64,
    })
}

fn read_exact(reader: &mut impl Read, buf: &mut [u8], path: &Path, offset: usize) -> Result<()> {
    reader.read_exact(buf).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            FormatError::Truncated {
                path: path.to_path_buf(),
                offset: offset as u64,
                what: format!("the .npy header needs {} more bytes", buf.len()),
            }
        } else {
            FormatError::Io {
                path: path.to_path_buf(),
                offset: offset as u64,
                source: e,
            }
        }
    })
}

/// A value of the header's Python dict literal.
#[derive(Clone, Debug, PartialEq)]
enum Value {
    Str(String),
    Bool(bool),
    Tuple(Vec<usize>),
}

impl Value {
    fn as_str(&self) -> Option<&str> {
        match self {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }
    fn as_bool(&self) -> Option<bool> {
        match self {
            Value::Bool(b) => Some(*b),
            _ => None,
        }
    }
    fn as_tuple(&self) -> Option<&[usize]> {
        match self {
            Value::Tuple(t) => Some(t),
            _ => None,
        }
    }
}

/// The header's dict: `{'key': value, ...}` with string, `True`/`False` and integer-tuple values,
/// the only kinds NumPy writes there.
struct Dict(Vec<(String, Value)>);

impl Dict {
    fn get(&self, key: &str) -> Option<&Value> {
        self.0.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    fn parse(text: &str) -> std::result::Result<Dict, String> {
        let mut p = Parser {
            s: text.as_bytes(),
            i: 0,
        };
        p.expect(b'{')?;
        let mut items = Vec::new();
        loop {
            p.skip_space();
            if p.eat(b'}') {
                break;
            }
            let key = p.string()?;
            p.expect(b':')?;
            let value = p.value()?;
            items.push((key, value));
            p.skip_space();
            if p.eat(b',') {
                continue;
            }
            p.expect(b'}')?;
            break;
        }
        p.skip_space();
        if p.i != p.s.len() {
            return Err(format!("text after the dict at character {}", p.i));
        }
        Ok(Dict(items))
    }
}

struct Parser<'a> {
    s: &'a [u8],
    i: usize,
}

impl Parser<'_> {
    fn skip_space(&mut self) {
        while self.s.get(self.i).is_some_and(u8::is_ascii_whitespace) {
            self.i += 1;
        }
    }

    fn eat(&mut self, c: u8) -> bool {
        self.skip_space();
        if self.s.get(self.i) == Some(&c) {
            self.i += 1;
            true
        } else {
            false
        }
    }

    fn expect(&mut self, c: u8) -> std::result::Result<(), String> {
        if self.eat(c) {
            Ok(())
        } else {
            Err(format!("`{}` expected at character {}", c as char, self.i))
        }
    }

    fn string(&mut self) -> std::result::Result<String, String> {
        self.skip_space();
        let quote = match self.s.get(self.i) {
            Some(&q @ (b'\'' | b'"')) => q,
            _ => return Err(format!("a quoted string expected at character {}", self.i)),
        };
        let start = self.i + 1;
        let len = self.s[start..]
            .iter()
            .position(|&c| c == quote)
            .ok_or_else(|| format!("unterminated string at character {}", self.i))?;
        self.i = start + len + 1;
        String::from_utf8(self.s[start..start + len].to_vec())
            .map_err(|_| format!("a string that is not UTF-8 at character {start}"))
    }

    fn value(&mut self) -> std::result::Result<Value, String> {
        self.skip_space();
        let rest = &self.s[self.i..];
        if rest.starts_with(b"True") {
            self.i += 4;
            return Ok(Value::Bool(true));
        }
        if rest.starts_with(b"False") {
            self.i += 5;
            return Ok(Value::Bool(false));
        }
        match rest.first() {
            Some(b'\'' | b'"') => self.string().map(Value::Str),
            Some(b'(') => {
                self.i += 1;
                let mut dims = Vec::new();
                loop {
                    if self.eat(b')') {
                        break;
                    }
                    dims.push(self.integer()?);
                    if self.eat(b',') {
                        continue;
                    }
                    self.expect(b')')?;
                    break;
                }
                Ok(Value::Tuple(dims))
            }
            _ => Err(format!("a value expected at character {}", self.i)),
        }
    }

    fn integer(&mut self) -> std::result::Result<usize, String> {
        self.skip_space();
        let start = self.i;
        while self.s.get(self.i).is_some_and(u8::is_ascii_digit) {
            self.i += 1;
        }
        // Python 2's long suffix.
        let digits = &self.s[start..self.i];
        if self.s.get(self.i) == Some(&b'L') {
            self.i += 1;
        }
        std::str::from_utf8(digits)
            .ok()
            .and_then(|d| d.parse::<usize>().ok())
            .ok_or_else(|| format!("a dimension expected at character {start}"))
    }
}

/// A float32 `[T, H, W]` `.npy` file, read a frame at a time; or, opened with
/// [`open_samples`](NpyFrames::open_samples), `[N, C, .., H, W]` read a sample (`C .. H W`
/// values) at a time.
pub struct NpyFrames {
    path: PathBuf,
    reader: BufReader<File>,
    frames: usize,
    /// Values of the axes between the first and the last two (1 for `[T, H, W]`).
    planes: usize,
    height: usize,
    width: usize,
    fortran_order: bool,
    data_offset: u64,
    next: usize,
    bytes: Vec<u8>,
}

impl NpyFrames {
    /// Opens `path` and checks its header: float32 (`<f4`), three axes, and a file size that
    /// holds the shape exactly.
    ///
    /// # Errors
    /// The file cannot be opened or read, or its header or size says something else.
    pub fn open(path: impl AsRef<Path>) -> Result<NpyFrames> {
        Self::open_axes(path.as_ref(), false)
    }

    /// Opens `path` as [`open`](Self::open) does, for any float32 array of three axes or more,
    /// `[N, ..]`: each [`read_frame`](Self::read_frame) reads one sample, `[..]` (e.g. a
    /// `[C, H, W]` representation of a `[N, C, H, W]` set).
    ///
    /// # Errors
    /// As [`open`](Self::open), but for the number of axes.
    pub fn open_samples(path: impl AsRef<Path>) -> Result<NpyFrames> {
        Self::open_axes(path.as_ref(), true)
    }

    fn open_axes(path: &Path, samples: bool) -> Result<NpyFrames> {
        let open_err = |source| FormatError::Open {
            path: path.to_path_buf(),
            source,
        };
        let file = File::open(path).map_err(open_err)?;
        let size = file.metadata().map_err(open_err)?.len();
        let mut reader = BufReader::new(file);
        let header = parse_header(&mut reader, path)?;
        let bad = |what: String| FormatError::Header {
            path: path.to_path_buf(),
            what,
        };
        if header.descr != "<f4" {
            return Err(bad(format!(
                "descr '{}': frames must be little-endian float32 ('<f4')",
                header.descr
            )));
        }
        let (frames, planes, height, width) = match header.shape.as_slice() {
            &[frames, height, width] => (frames, 1, height, width),
            &[frames, ref middle @ .., height, width] if samples => {
                let planes = middle.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
                let Some(planes) = planes else {
                    return Err(bad(format!("shape {:?}: over 2^64 values", header.shape)));
                };
                (frames, planes, height, width)
            }
            shape if samples => {
                return Err(bad(format!(
                    "shape {shape:?}: samples must be [N, .., H, W], three axes or more"
                )));
            }
            shape => {
                return Err(bad(format!("shape {shape:?}: frames must be [T, H, W]")));
            }
        };
        let want = frames
            .checked_mul(planes)
            .and_then(|n| n.checked_mul(height))
            .and_then(|n| n.checked_mul(width))
            .and_then(|n| n.checked_mul(4))
            .and_then(|n| u64::try_from(n).ok())
            .and_then(|n| n.checked_add(header.data_offset));
        if want != Some(size) {
            return Err(FormatError::Truncated {
                path: path.to_path_buf(),
                offset: size,
                what: format!(
                    "shape {:?} of float32 needs {} bytes, the file has {size}",
                    header.shape,
                    want.map_or_else(|| "more than 2^64".to_string(), |w| w.to_string())
                ),
            });
        }
        Ok(NpyFrames {
            path: path.to_path_buf(),
            reader,
            frames,
            planes,
            height,
            width,
            fortran_order: header.fortran_order,
            data_offset: header.data_offset,
            next: 0,
            bytes: Vec::new(),
        })
    }

    /// `[T, H, W]` (of samples: their count and the last two axes).
    pub fn shape(&self) -> (usize, usize, usize) {
        (self.frames, self.height, self.width)
    }

    /// Whether the file is in Fortran order: then [`NpyFrames::read_frame`] refuses, and the
    /// file is to be read whole.
    pub fn fortran_order(&self) -> bool {
        self.fortran_order
    }

    /// Values of one frame or sample (`H * W`, or the product of every axis but the first).
    pub fn frame_len(&self) -> usize {
        self.planes * self.height * self.width
    }

    /// Reads the next frame into `frame` (`H * W` values, rows top-down; a sample's
    /// [`frame_len`](Self::frame_len) values in C order); `false` after the last.
    ///
    /// # Errors
    /// A Fortran-order file, or a read that fails.
    pub fn read_frame(&mut self, frame: &mut Vec<f32>) -> Result<bool> {
        if self.fortran_order {
            return Err(FormatError::Header {
                path: self.path.clone(),
                what: "fortran_order True: frames cannot be read one at a time".into(),
            });
        }
        if self.next == self.frames {
            return Ok(false);
        }
        let n = self.frame_len();
        self.bytes.resize(n * 4, 0);
        let offset = self.data_offset + (self.next * n * 4) as u64;
        self.reader
            .read_exact(&mut self.bytes)
            .map_err(|source| FormatError::Io {
                path: self.path.clone(),
                offset,
                source,
            })?;
        frame.clear();
        frame.extend(
            self.bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        );
        self.next += 1;
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;

    fn header_of(bytes: &[u8]) -> Result<NpyHeader> {
        parse_header(&mut &bytes[..], Path::new("mem.npy"))
    }

    #[test]
    fn frames_come_back_one_at_a_time_as_numpy_wrote_them() {
        let dir = tempfile::tempdir().expect("tempdir");
        let a = Array3::from_shape_fn((3, 2, 5), |(t, y, x)| (t * 100 + y * 10 + x) as f32);
        let path = dir.path().join("f.npy");
        ndarray_npy::write_npy(&path, &a).expect("write");
        let mut r = NpyFrames::open(&path).expect("open");
        assert_eq!(r.shape(), (3, 2, 5));
        assert!(!r.fortran_order());
        let mut f = Vec::new();
        for t in 0..3 {
            assert!(r.read_frame(&mut f).expect("frame"));
            let want: Vec<f32> = a.index_axis(ndarray::Axis(0), t).iter().copied().collect();
            assert_eq!(f, want);
        }
        assert!(!r.read_frame(&mut f).expect("end"));
        // Fortran order is said, and not read a frame at a time.
        let fortran = a.t().as_standard_layout().t().to_owned();
        ndarray_npy::write_npy(&path, &fortran).expect("write");
        let mut r = NpyFrames::open(&path).expect("open");
        assert!(r.fortran_order());
        assert!(r.read_frame(&mut f).is_err());
    }

    #[test]
    fn samples_of_four_axes_come_back_one_at_a_time() {
        let dir = tempfile::tempdir().expect("tempdir");
        let a = ndarray::Array4::from_shape_fn((3, 2, 4, 5), |(n, c, y, x)| {
            (n * 1000 + c * 100 + y * 10 + x) as f32
        });
        let path = dir.path().join("s.npy");
        ndarray_npy::write_npy(&path, &a).expect("write");
        // Frames are three axes, nothing else.
        let e = NpyFrames::open(&path).err().expect("refused").to_string();
        assert!(e.contains("[3, 2, 4, 5]") && e.contains("[T, H, W]"), "{e}");
        let mut r = NpyFrames::open_samples(&path).expect("open");
        assert_eq!((r.shape(), r.frame_len()), ((3, 4, 5), 40));
        let mut f = Vec::new();
        for n in 0..3 {
            assert!(r.read_frame(&mut f).expect("sample"));
            let want: Vec<f32> = a.index_axis(ndarray::Axis(0), n).iter().copied().collect();
            assert_eq!(f, want);
        }
        assert!(!r.read_frame(&mut f).expect("end"));
        // Three axes read as frames; fewer are refused; a size short of the shape too.
        let three = Array3::from_shape_fn((2, 3, 4), |(t, y, x)| (t + y + x) as f32);
        ndarray_npy::write_npy(&path, &three).expect("write");
        assert_eq!(
            NpyFrames::open_samples(&path).expect("open").frame_len(),
            12
        );
        ndarray_npy::write_npy(&path, &ndarray::Array2::<f32>::zeros((2, 3))).expect("write");
        let e = NpyFrames::open_samples(&path)
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("three axes or more"), "{e}");
        let e = {
            std::fs::write(&path, b"\x93NUMPY\x01\x00\x3f\x00{'descr': '<f4', 'fortran_order': False, 'shape': (9, 9, 9, 9)}")
                .expect("write");
            NpyFrames::open_samples(&path)
                .err()
                .expect("refused")
                .to_string()
        };
        assert!(e.contains("needs") && e.contains("the file has"), "{e}");
    }

    #[test]
    fn headers_of_every_version_and_spelling_parse() {
        let h = header_of(
            b"\x93NUMPY\x01\x00\x44\x00{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 4), }     \n",
        )
        .expect("v1");
        assert_eq!(
            (
                h.descr.as_str(),
                h.fortran_order,
                h.shape.as_slice(),
                h.data_offset
            ),
            ("<f4", false, &[2, 3, 4][..], 78)
        );
        let text = b"{\"shape\": (7L,), \"descr\": \"<f4\", \"fortran_order\": True}\n";
        let mut v2 = b"\x93NUMPY\x02\x00".to_vec();
        v2.extend((text.len() as u32).to_le_bytes());
        v2.extend(text);
        let h = header_of(&v2).expect("v2");
        assert_eq!((h.fortran_order, h.shape), (true, vec![7]));
    }

    #[test]
    fn bad_files_are_refused_by_name_and_field() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("f.npy");
        let err = |bytes: &[u8]| {
            std::fs::write(&path, bytes).expect("write");
            NpyFrames::open(&path).err().expect("refused").to_string()
        };
        assert!(err(b"PK\x03\x04 a zip").contains("not an .npy file"));
        assert!(err(b"\x93NUMPY\x09\x00").contains("version 9.0"));
        let e = err(b"\x93NUMPY\x01\x00\x3c\x00{'descr': '<f8', 'fortran_order': False, 'shape': (1, 1, 1)}");
        assert!(e.contains("f.npy") && e.contains("'<f8'"), "{e}");
        let e = err(
            b"\x93NUMPY\x01\x00\x39\x00{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2)}",
        );
        assert!(e.contains("[2, 2]") && e.contains("[T, H, W]"), "{e}");
        // The shape claims far more than the file holds: refused before any allocation.
        let e = err(b"\x93NUMPY\x01\x00\x4b\x00{'descr': '<f4', 'fortran_order': False, 'shape': (100000, 100000, 100000)}");
        assert!(e.contains("needs") && e.contains("the file has"), "{e}");
        let e = err(b"\x93NUMPY\x02\x00\xff\xff\xff\xff");
        assert!(e.contains("header length"), "{e}");
        let e = err(b"\x93NUMPY\x01\x00\x20\x00{'descr': '<f4', 'shape': (1,");
        assert!(e.contains("f.npy") && e.contains("header"), "{e}");
    }

    proptest::proptest! {
        #[test]
        fn any_bytes_give_a_header_or_an_error_never_a_panic(
            tail in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200),
            version in 0u8..5,
        ) {
            let mut bytes = b"\x93NUMPY".to_vec();
            bytes.push(version);
            bytes.push(0);
            bytes.extend(&tail);
            let _ = header_of(&bytes);
            let mut dict = b"\x93NUMPY\x01\x00".to_vec();
            dict.extend((tail.len() as u16).to_le_bytes());
            dict.extend(&tail);
            let _ = header_of(&dict);
        }
    }
}
