//! PKU spike-camera `.dat` files (Vidar): no header, just spike planes one after the other.
//!
//! A stored plane is `height` rows of `width + head_columns` pixels, row-major, pixel `k` at bit
//! `k & 7` (least significant first) of byte `k >> 3`, with the rows stored **bottom-up** (the
//! first stored row is the bottom of the image). Every plane starts on a byte boundary. Some
//! cameras store 16 extra "head" columns at the end of each row (416-pixel rows for a 400-pixel
//! image, as the public Vidar loaders' `remove_head` option drops with `spikes[:, :, :-16]`);
//! [`PkuGeometry::head_columns`] says so and the reader drops them.
//!
//! The reader turns planes into [`SpikeChunk`]s in the pipeline's layout: same bit order, rows
//! **top-down**, no head columns ([`neuspike_schemas::bytes_per_plane`] bytes a plane). The
//! writer flips back. Nothing in a file says its resolution, so the caller gives it (default
//! 400x250); a size that is not a whole number of planes is reported, after the whole planes,
//! as [`FormatError::PartialPlane`] (or up front by [`plane_count`]).

use std::fmt;
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use neuspike_schemas::{SpikeChunk, bytes_per_plane};

use crate::binary::{Out, WriteSummary};
use crate::error::{FormatError, Result};
use crate::header::read_full;

/// Width of the PKU Vidar camera.
pub const DEFAULT_WIDTH: usize = 400;
/// Height of the PKU Vidar camera.
pub const DEFAULT_HEIGHT: usize = 250;
/// Extra columns some recordings store at the end of each row.
pub const HEAD_COLUMNS: usize = 16;
/// 20 kHz, the Vidar camera's plane rate.
pub const DEFAULT_PLANE_PERIOD_NS: i64 = 50_000;

/// The shape of the planes in a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PkuGeometry {
    /// Image width in pixels (head columns not included).
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Extra columns stored at the end of each row and dropped on reading (0 or [`HEAD_COLUMNS`]).
    pub head_columns: usize,
}

impl Default for PkuGeometry {
    fn default() -> Self {
        PkuGeometry::new(DEFAULT_WIDTH, DEFAULT_HEIGHT)
    }
}

impl fmt::Display for PkuGeometry {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}", self.width, self.height)?;
        if self.head_columns > 0 {
            write!(f, " + {} head columns", self.head_columns)?;
        }
        Ok(())
    }
}

impl PkuGeometry {
    /// Planes of `width x height` without head columns.
    pub const fn new(width: usize, height: usize) -> Self {
        PkuGeometry {
            width,
            height,
            head_columns: 0,
        }
    }

    /// Planes of `width x height` stored with [`HEAD_COLUMNS`] extra columns a row.
    pub const fn with_head(width: usize, height: usize) -> Self {
        PkuGeometry {
            width,
            height,
            head_columns: HEAD_COLUMNS,
        }
    }

    /// Pixels in a stored row.
    pub fn stored_width(&self) -> usize {
        self.width + self.head_columns
    }

    /// Bytes of one plane in the file.
    pub fn stored_plane_bytes(&self) -> usize {
        bytes_per_plane(self.stored_width(), self.height)
    }

    /// Bytes of one plane in the pipeline's layout ([`SpikeChunk::bits`]).
    pub fn plane_bytes(&self) -> usize {
        bytes_per_plane(self.width, self.height)
    }

    fn check(&self, path: &Path) -> Result<()> {
        if self.width == 0 || self.height == 0 {
            return Err(FormatError::Unsupported {
                path: path.to_path_buf(),
                what: format!("an empty plane geometry {self}"),
            });
        }
        Ok(())
    }
}

/// How to read a spike file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PkuOptions {
    /// Plane shape.
    pub geometry: PkuGeometry,
    /// Time between planes (> 0).
    pub plane_period_ns: i64,
    /// Time of the first plane.
    pub t_first_ns: i64,
}

impl Default for PkuOptions {
    fn default() -> Self {
        PkuOptions {
            geometry: PkuGeometry::default(),
            plane_period_ns: DEFAULT_PLANE_PERIOD_NS,
            t_first_ns: 0,
        }
    }
}

/// Copies one stored plane (bottom-up rows of `stored_width` pixels) into `dst` (top-down rows
/// of `width` pixels, `g.plane_bytes()` long). Byte-aligned rows take a row-copy fast path,
/// checked against [`plane_from_stored_scalar`].
///
/// # Panics
/// If `stored` is shorter than `g.stored_plane_bytes()` or `dst` than `g.plane_bytes()`.
pub fn plane_from_stored(stored: &[u8], dst: &mut [u8], g: &PkuGeometry) {
    let (w, ws, h) = (g.width, g.stored_width(), g.height);
    if w % 8 == 0 && ws % 8 == 0 {
        let (rb, rbs) = (w / 8, ws / 8);
        for (y, row) in dst.chunks_exact_mut(rb).take(h).enumerate() {
            let src = (h - 1 - y) * rbs;
            row.copy_from_slice(&stored[src..src + rb]);
        }
    } else {
        plane_from_stored_scalar(stored, dst, g);
    }
}

/// The bit-by-bit reference for [`plane_from_stored`].
pub fn plane_from_stored_scalar(stored: &[u8], dst: &mut [u8], g: &PkuGeometry) {
    let (w, ws, h) = (g.width, g.stored_width(), g.height);
    dst.fill(0);
    for y in 0..h {
        for x in 0..w {
            let k = (h - 1 - y) * ws + x;
            if (stored[k >> 3] >> (k & 7)) & 1 != 0 {
                let j = y * w + x;
                dst[j >> 3] |= 1 << (j & 7);
            }
        }
    }
}

/// The inverse of [`plane_from_stored`]: head columns and padding bits are written as 0.
///
/// # Panics
/// If `plane` is shorter than `g.plane_bytes()` or `dst` than `g.stored_plane_bytes()`.
pub fn plane_to_stored(plane: &[u8], dst: &mut [u8], g: &PkuGeometry) {
    let (w, ws, h) = (g.width, g.stored_width(), g.height);
    if w % 8 == 0 && ws % 8 == 0 {
        let (rb, rbs) = (w / 8, ws / 8);
        dst.fill(0);
        for (y, row) in plane.chunks_exact(rb).take(h).enumerate() {
            let d = (h - 1 - y) * rbs;
            dst[d..d + rb].copy_from_slice(row);
        }
    } else {
        dst.fill(0);
        for y in 0..h {
            for x in 0..w {
                let j = y * w + x;
                if (plane[j >> 3] >> (j & 7)) & 1 != 0 {
                    let k = (h - 1 - y) * ws + x;
                    dst[k >> 3] |= 1 << (k & 7);
                }
            }
        }
    }
}

/// A streaming reader of PKU spike planes.
pub struct PkuReader<R: Read> {
    r: R,
    path: PathBuf,
    opts: PkuOptions,
    stored: Vec<u8>,
    planes_read: u64,
    bytes_read: u64,
    seq: u64,
    pending: Option<FormatError>,
    done: bool,
}

impl PkuReader<File> {
    /// Opens a spike file. A file smaller than one plane is refused at once
    /// ([`FormatError::ResolutionMismatch`]); an empty one too ([`FormatError::Empty`]).
    pub fn open(path: impl AsRef<Path>, opts: &PkuOptions) -> Result<Self> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|source| FormatError::Open {
            path: path.to_path_buf(),
            source,
        })?;
        let size = file
            .metadata()
            .map_err(|source| FormatError::Open {
                path: path.to_path_buf(),
                source,
            })?
            .len();
        opts.geometry.check(path)?;
        let plane = opts.geometry.stored_plane_bytes() as u64;
        if size == 0 {
            return Err(FormatError::Empty {
                path: path.to_path_buf(),
            });
        }
        if size < plane {
            return Err(mismatch(path, size, &opts.geometry));
        }
        Self::from_reader(file, path, opts)
    }
}

fn mismatch(path: &Path, size: u64, g: &PkuGeometry) -> FormatError {
    let plane = g.stored_plane_bytes() as u64;
    FormatError::ResolutionMismatch {
        path: path.to_path_buf(),
        size,
        plane_bytes: plane,
        geometry: g.to_string(),
        whole_planes: size / plane,
        remainder: size % plane,
    }
}

/// The number of planes in a spike file, or [`FormatError::ResolutionMismatch`] naming the file,
/// its size and the plane size when the size is not a whole number of planes.
pub fn plane_count(path: impl AsRef<Path>, geometry: &PkuGeometry) -> Result<u64> {
    let path = path.as_ref();
    geometry.check(path)?;
    let size = std::fs::metadata(path)
        .map_err(|source| FormatError::Open {
            path: path.to_path_buf(),
            source,
        })?
        .len();
    if size == 0 {
        return Err(FormatError::Empty {
            path: path.to_path_buf(),
        });
    }
    let plane = geometry.stored_plane_bytes() as u64;
    if size % plane != 0 {
        return Err(mismatch(path, size, geometry));
    }
    Ok(size / plane)
}

impl<R: Read> PkuReader<R> {
    /// Reads planes from `r`, named `name` in errors.
    pub fn from_reader(r: R, name: impl Into<PathBuf>, opts: &PkuOptions) -> Result<Self> {
        let path = name.into();
        opts.geometry.check(&path)?;
        if opts.plane_period_ns <= 0 {
            return Err(FormatError::Unsupported {
                path,
                what: format!("plane period {} ns (must be > 0)", opts.plane_period_ns),
            });
        }
        Ok(PkuReader {
            r,
            path,
            opts: *opts,
            stored: Vec::new(),
            planes_read: 0,
            bytes_read: 0,
            seq: 0,
            pending: None,
            done: false,
        })
    }

    /// Planes delivered so far.
    pub fn planes_read(&self) -> u64 {
        self.planes_read
    }

    /// The options in use.
    pub fn options(&self) -> &PkuOptions {
        &self.opts
    }

    /// The next (up to) `n` planes, top-down, as a chunk numbered by `seq` from 0 and stamped
    /// `t_first_ns + plane * plane_period_ns`; `None` at the end. A trailing partial plane is
    /// reported as [`FormatError::PartialPlane`] on the call after the last whole planes.
    pub fn next_chunk(&mut self, n: usize) -> Result<Option<SpikeChunk>> {
        if let Some(e) = self.pending.take() {
            self.done = true;
            return Err(e);
        }
        if self.done {
            return Ok(None);
        }
        let g = self.opts.geometry;
        let sp = g.stored_plane_bytes();
        self.stored.resize(n.max(1).saturating_mul(sp), 0);
        let got = read_full(&mut self.r, &mut self.stored).map_err(|source| {
            self.done = true;
            FormatError::Io {
                path: self.path.clone(),
                offset: self.bytes_read,
                source,
            }
        })?;
        let start = self.bytes_read;
        self.bytes_read += got as u64;
        if got == 0 {
            self.done = true;
            if start == 0 {
                return Err(FormatError::Empty {
                    path: self.path.clone(),
                });
            }
            return Ok(None);
        }
        let whole = got / sp;
        let tail = got % sp;
        if tail > 0 {
            let e = FormatError::PartialPlane {
                path: self.path.clone(),
                size: self.bytes_read,
                plane_bytes: sp as u64,
                geometry: g.to_string(),
                whole_planes: self.planes_read + whole as u64,
                tail_offset: start + (whole * sp) as u64,
                tail_bytes: tail as u64,
            };
            if whole == 0 {
                self.done = true;
                return Err(e);
            }
            self.pending = Some(e);
        } else if got < self.stored.len() {
            self.done = true;
        }
        let pb = g.plane_bytes();
        let mut bits = vec![0u8; whole * pb];
        for (src, dst) in self
            .stored
            .chunks_exact(sp)
            .take(whole)
            .zip(bits.chunks_exact_mut(pb.max(1)))
        {
            plane_from_stored(src, dst, &g);
        }
        let first_plane = self.planes_read;
        let t_first_ns = self.opts.t_first_ns.saturating_add(
            i64::try_from(first_plane)
                .unwrap_or(i64::MAX)
                .saturating_mul(self.opts.plane_period_ns),
        );
        self.planes_read += whole as u64;
        let chunk = SpikeChunk {
            width: g.width,
            height: g.height,
            first_plane,
            n_planes: whole,
            t_first_ns,
            plane_period_ns: self.opts.plane_period_ns,
            seq: self.seq,
            bits,
            lum_per_rate: None,
        };
        self.seq += 1;
        Ok(Some(chunk))
    }

    /// An iterator over chunks of up to `n` planes; it ends after the first error.
    pub fn into_chunks(self, n: usize) -> PkuChunks<R> {
        PkuChunks { reader: self, n }
    }
}

/// Chunks of planes; see [`PkuReader::into_chunks`].
pub struct PkuChunks<R: Read> {
    reader: PkuReader<R>,
    n: usize,
}

impl<R: Read> PkuChunks<R> {
    /// The reader.
    pub fn reader(&self) -> &PkuReader<R> {
        &self.reader
    }
}

impl<R: Read> Iterator for PkuChunks<R> {
    type Item = Result<SpikeChunk>;

    fn next(&mut self) -> Option<Self::Item> {
        self.reader.next_chunk(self.n).transpose()
    }
}

/// Writes spike planes as a PKU `.dat` file: rows flipped back to bottom-up, head columns (if the
/// geometry has them) written as zeros.
pub struct PkuWriter<W: Write> {
    out: Out<W>,
    geometry: PkuGeometry,
    scratch: Vec<u8>,
    summary: WriteSummary,
}

impl<W: Write> PkuWriter<W> {
    /// Starts a file on `w` (named `name` in errors) with planes of `geometry`.
    pub fn new(w: W, name: impl Into<PathBuf>, geometry: PkuGeometry) -> Result<Self> {
        let path = name.into();
        geometry.check(&path)?;
        Ok(PkuWriter {
            out: Out::new(w, path),
            geometry,
            scratch: vec![0; geometry.stored_plane_bytes()],
            summary: WriteSummary::default(),
        })
    }

    /// Appends planes in the pipeline's layout (a whole number of
    /// `geometry.plane_bytes()`-byte planes).
    pub fn write_planes(&mut self, bits: &[u8]) -> Result<()> {
        let pb = self.geometry.plane_bytes();
        if !bits.len().is_multiple_of(pb) {
            return Err(self.out.unwritable(
                self.summary.items,
                format!(
                    "{} bytes are not a whole number of {pb}-byte {} planes",
                    bits.len(),
                    self.geometry
                ),
            ));
        }
        for plane in bits.chunks_exact(pb) {
            plane_to_stored(plane, &mut self.scratch, &self.geometry);
            self.out.put(&self.scratch)?;
            self.summary.items += 1;
        }
        Ok(())
    }

    /// Appends the planes of a chunk of this writer's size.
    pub fn write_chunk(&mut self, chunk: &SpikeChunk) -> Result<()> {
        let g = self.geometry;
        if chunk.width != g.width || chunk.height != g.height {
            return Err(self.out.unwritable(
                self.summary.items,
                format!(
                    "a {}x{} chunk in a {}x{} file",
                    chunk.width, chunk.height, g.width, g.height
                ),
            ));
        }
        self.write_planes(&chunk.bits)
    }

    /// Flushes and returns the sink and what was written.
    pub fn finish(self) -> Result<(W, WriteSummary)> {
        self.out.finish_with(self.summary)
    }
}

/// A summary of a spike file.
#[derive(Clone, Debug, PartialEq)]
pub struct SpikeInfo {
    /// The file.
    pub path: PathBuf,
    /// Plane shape assumed.
    pub geometry: PkuGeometry,
    /// File size.
    pub bytes: u64,
    /// Whole planes.
    pub planes: u64,
    /// Spikes in all.
    pub spikes: u64,
    /// Time between planes.
    pub plane_period_ns: i64,
    /// Time of the first plane.
    pub t_first_ns: i64,
    /// A trailing partial plane: (byte offset, bytes). The whole planes are still counted.
    pub partial_tail: Option<(u64, u64)>,
}

impl SpikeInfo {
    /// Time of the last plane.
    pub fn t_last_ns(&self) -> i64 {
        let last = i64::try_from(self.planes.saturating_sub(1)).unwrap_or(i64::MAX);
        self.t_first_ns
            .saturating_add(last.saturating_mul(self.plane_period_ns))
    }

    /// Time the planes cover: `planes * plane_period_ns` (each plane integrates one period).
    pub fn duration_ns(&self) -> i64 {
        i64::try_from(self.planes)
            .unwrap_or(i64::MAX)
            .saturating_mul(self.plane_period_ns)
    }

    /// Mean spikes per plane.
    pub fn spikes_per_plane(&self) -> f64 {
        if self.planes == 0 {
            0.0
        } else {
            self.spikes as f64 / self.planes as f64
        }
    }

    /// Mean firing probability of a pixel in a plane.
    pub fn firing_probability(&self) -> f64 {
        let px = (self.geometry.width * self.geometry.height) as f64;
        if px == 0.0 {
            0.0
        } else {
            self.spikes_per_plane() / px
        }
    }

    /// Planes per second.
    pub fn plane_rate_hz(&self) -> f64 {
        1e9 / self.plane_period_ns as f64
    }
}

impl fmt::Display for SpikeInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{}: PKU spike planes, {}",
            self.path.display(),
            self.geometry
        )?;
        writeln!(
            f,
            "  {} planes at {:.0} Hz ({} ns each), {} bytes",
            self.planes,
            self.plane_rate_hz(),
            self.plane_period_ns,
            self.bytes
        )?;
        writeln!(
            f,
            "  first plane at {} ns, last at {} ns, covering {} ns",
            self.t_first_ns,
            self.t_last_ns(),
            self.duration_ns()
        )?;
        write!(
            f,
            "  {} spikes, {:.1} per plane, firing probability {:.3}",
            self.spikes,
            self.spikes_per_plane(),
            self.firing_probability()
        )?;
        if let Some((off, n)) = self.partial_tail {
            write!(f, "\n  WARNING: {n} bytes of a partial plane at byte {off}")?;
        }
        Ok(())
    }
}

/// Summarises a spike file by reading it once, a chunk at a time. A trailing partial plane is
/// reported in [`SpikeInfo::partial_tail`] rather than as an error.
pub fn info(path: impl AsRef<Path>, opts: &PkuOptions) -> Result<SpikeInfo> {
    let path = path.as_ref();
    let mut reader = PkuReader::open(path, opts)?;
    let mut info = SpikeInfo {
        path: path.to_path_buf(),
        geometry: opts.geometry,
        bytes: 0,
        planes: 0,
        spikes: 0,
        plane_period_ns: opts.plane_period_ns,
        t_first_ns: opts.t_first_ns,
        partial_tail: None,
    };
    loop {
        match reader.next_chunk(64) {
            Ok(Some(c)) => {
                info.planes += c.n_planes as u64;
                info.spikes += c.spike_count();
            }
            Ok(None) => break,
            Err(FormatError::PartialPlane {
                tail_offset,
                tail_bytes,
                ..
            }) => {
                info.partial_tail = Some((tail_offset, tail_bytes));
                break;
            }
            Err(e) => return Err(e),
        }
    }
    info.bytes = reader.bytes_read;
    Ok(info)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(n: usize, mut s: u64) -> Vec<u8> {
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                s as u8
            })
            .collect()
    }

    #[test]
    fn fast_flip_matches_scalar_reference() {
        for g in [
            PkuGeometry::new(400, 250),
            PkuGeometry::with_head(400, 250),
            PkuGeometry::new(16, 3),
            PkuGeometry::new(8, 1),
        ] {
            let stored = noise(g.stored_plane_bytes(), 7);
            let mut fast = vec![0; g.plane_bytes()];
            let mut slow = vec![0xFF; g.plane_bytes()];
            plane_from_stored(&stored, &mut fast, &g);
            plane_from_stored_scalar(&stored, &mut slow, &g);
            assert_eq!(fast, slow, "{g}");
        }
    }

    #[test]
    fn flip_puts_the_first_stored_row_at_the_bottom() {
        // 8x2: stored row 0 (bottom of the image) has pixel 0 set.
        let g = PkuGeometry::new(8, 2);
        let mut dst = [0u8; 2];
        plane_from_stored(&[0b0000_0001, 0], &mut dst, &g);
        assert_eq!(dst, [0, 0b0000_0001]);
        // Odd width, scalar path: 3x3, stored k=0 -> image row 2, x 0 -> bit 6.
        let g = PkuGeometry::new(3, 3);
        let mut dst = [0u8; 2];
        plane_from_stored(&[0b0000_0001, 0], &mut dst, &g);
        assert_eq!(dst, [0b0100_0000, 0]);
        let mut back = [0u8; 2];
        plane_to_stored(&dst, &mut back, &g);
        assert_eq!(back, [0b0000_0001, 0]);
    }

    #[test]
    fn odd_geometry_round_trips_through_the_writer() {
        let g = PkuGeometry::new(5, 3);
        let mut planes = noise(3 * g.plane_bytes(), 3);
        // Padding bits beyond the 15 pixels are not part of the image.
        for p in planes.chunks_exact_mut(g.plane_bytes()) {
            p[1] &= 0x7F;
        }
        let mut w = PkuWriter::new(Vec::new(), "mem", g).unwrap();
        w.write_planes(&planes).unwrap();
        let (bytes, s) = w.finish().unwrap();
        assert_eq!(s.items, 3);
        let opts = PkuOptions {
            geometry: g,
            ..PkuOptions::default()
        };
        let mut r = PkuReader::from_reader(&bytes[..], "mem", &opts).unwrap();
        let c = r.next_chunk(10).unwrap().unwrap();
        assert_eq!(c.bits, planes);
        assert!(r.next_chunk(10).unwrap().is_none());
    }
}
