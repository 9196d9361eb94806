//! Ground-truth folders: luminance frames beside a recording, listed by the plane they belong to.
//!
//! `timestamps.txt` holds one line per frame, `plane t_ns file` (`#` comments and blank lines
//! allowed), planes strictly increasing, each file a name inside the folder. `neuspike simulate`
//! writes such a folder (`ground-truth/`); the spike source plays it beside the planes.

use std::io::{Read, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// The list's file name inside the folder.
pub const LIST: &str = "timestamps.txt";
/// The list's first line, naming its columns.
pub const HEADER: &str = "# plane t_ns file";
/// The largest list read: 64 MiB, over a million frames' lines. A longer file is refused before
/// it is read whole.
pub const MAX_LIST_BYTES: u64 = 64 << 20;

/// Why a ground-truth list could not be read. Each names the file, and the line with its text.
#[derive(Debug, thiserror::Error)]
pub enum TruthError {
    /// The list could not be read.
    #[error("{}: cannot read the ground-truth list", path.display())]
    Read {
        /// `timestamps.txt`.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The list is longer than [`MAX_LIST_BYTES`].
    #[error("{}: longer than {limit} bytes, the most a ground-truth list may hold", path.display())]
    TooLong {
        /// `timestamps.txt`.
        path: PathBuf,
        /// [`MAX_LIST_BYTES`].
        limit: u64,
    },
    /// A line that is not a valid entry.
    #[error("{} line {line}: `{text}`: {why}", path.display())]
    Line {
        /// `timestamps.txt`.
        path: PathBuf,
        /// The line number, from 1.
        line: usize,
        /// The line as written.
        text: String,
        /// What is wrong with it.
        why: &'static str,
    },
}

/// A ground-truth folder's list: the planes that have a frame, in order, and their files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TruthList {
    /// `timestamps.txt`, as errors name it.
    pub path: PathBuf,
    /// `(plane, PNG path)`, planes strictly increasing.
    pub frames: Vec<(u64, PathBuf)>,
}

impl TruthList {
    /// Reads `dir/timestamps.txt`: a line that is not `plane t_ns file`, a plane that does not
    /// increase, or a file name leaving the folder is an error naming the line and its text.
    pub fn open(dir: &Path) -> Result<Self, TruthError> {
        let path = dir.join(LIST);
        let read_error = |source| TruthError::Read {
            path: path.clone(),
            source,
        };
        let mut text = String::new();
        std::fs::File::open(&path)
            .and_then(|f| f.take(MAX_LIST_BYTES + 1).read_to_string(&mut text))
            .map_err(read_error)?;
        if text.len() as u64 > MAX_LIST_BYTES {
            return Err(TruthError::TooLong {
                path,
                limit: MAX_LIST_BYTES,
            });
        }
        let mut frames: Vec<(u64, PathBuf)> = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let bad = |why| TruthError::Line {
                path: path.clone(),
                line: i + 1,
                text: line.to_string(),
                why,
            };
            let fields: Vec<&str> = line.split_whitespace().collect();
            let [plane, t_ns, file] = fields[..] else {
                return Err(bad("expected three fields: plane t_ns file"));
            };
            let plane: u64 = plane
                .parse()
                .map_err(|_| bad("the plane is not a whole number"))?;
            t_ns.parse::<i64>()
                .map_err(|_| bad("t_ns is not a whole number of nanoseconds"))?;
            if file.contains('/') || file.contains('\\') || file == ".." {
                return Err(bad("the file must be a name inside the folder"));
            }
            if let Some(&(last, _)) = frames.last()
                && plane <= last
            {
                return Err(bad("planes must increase down the list"));
            }
            frames.push((plane, dir.join(file)));
        }
        Ok(TruthList { path, frames })
    }

    /// The frames whose plane lies in `planes`.
    pub fn in_range(&self, planes: Range<u64>) -> &[(u64, PathBuf)] {
        let a = self.frames.partition_point(|f| f.0 < planes.start);
        let b = self.frames.partition_point(|f| f.0 < planes.end);
        &self.frames[a..b]
    }
}

/// Writes a ground-truth list: its header, then one entry per frame.
#[derive(Debug)]
pub struct TruthListWriter<W: Write> {
    w: W,
}

impl<W: Write> TruthListWriter<W> {
    /// Starts a list on `w` with its header line.
    pub fn new(mut w: W) -> std::io::Result<Self> {
        writeln!(w, "{HEADER}")?;
        Ok(TruthListWriter { w })
    }

    /// Appends the frame of `plane`, taken at `t_ns`, stored as `file` in the folder.
    pub fn entry(&mut self, plane: u64, t_ns: i64, file: &str) -> std::io::Result<()> {
        writeln!(self.w, "{plane} {t_ns} {file}")
    }

    /// Flushes and returns the writer.
    pub fn finish(mut self) -> std::io::Result<W> {
        self.w.flush()?;
        Ok(self.w)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn folder(list: &str) -> (tempfile::TempDir, Result<TruthList, TruthError>) {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(dir.path().join(LIST), list).expect("write");
        let t = TruthList::open(dir.path());
        (dir, t)
    }

    #[test]
    fn reads_the_list_and_picks_frames_by_plane() {
        let (dir, t) =
            folder("# plane t_ns file\n0 0 a.png\n\n20 1000000 b.png\n40 2000000 c.png\n");
        let t = t.expect("valid list");
        let planes: Vec<u64> = t.in_range(10..41).iter().map(|f| f.0).collect();
        assert_eq!(planes, [20, 40]);
        assert_eq!(t.in_range(0..1)[0].1, dir.path().join("a.png"));
        assert!(t.in_range(41..100).is_empty());
    }

    #[test]
    fn what_the_writer_writes_reads_back() {
        let mut w = TruthListWriter::new(Vec::new()).expect("header");
        w.entry(0, 0, "000000.png").expect("entry");
        w.entry(20, 1_000_000, "000020.png").expect("entry");
        let bytes = w.finish().expect("finish");
        let (dir, t) = folder(std::str::from_utf8(&bytes).expect("utf-8"));
        let t = t.expect("valid list");
        assert_eq!(
            t.frames,
            [
                (0, dir.path().join("000000.png")),
                (20, dir.path().join("000020.png"))
            ]
        );
    }

    #[test]
    fn a_list_longer_than_the_limit_is_refused_by_name() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = std::fs::File::create(dir.path().join(LIST)).expect("create");
        // sparse: the bytes read are what the limit lets through, not what the file claims
        f.set_len(MAX_LIST_BYTES + 1).expect("length");
        let e = TruthList::open(dir.path())
            .expect_err("too long")
            .to_string();
        assert!(
            e.ends_with(
                "timestamps.txt: longer than 67108864 bytes, the most a ground-truth list may hold"
            ),
            "{e}"
        );
        f.set_len(10).expect("length");
        let e = TruthList::open(dir.path())
            .expect_err("NUL bytes are not a line")
            .to_string();
        assert!(e.contains("line 1"), "{e}");
    }

    #[test]
    fn bad_lists_name_the_line_and_the_value() {
        for (list, line, why) in [
            ("0 0\n", 1, "three fields"),
            ("x 0 a.png\n", 1, "plane"),
            ("0 0 a.png\n5 1.5 b.png\n", 2, "t_ns"),
            ("0 0 ../a.png\n", 1, "inside the folder"),
            ("20 0 a.png\n20 0 b.png\n", 2, "increase"),
        ] {
            let (_dir, t) = folder(list);
            let e = t.expect_err(list).to_string();
            assert!(
                e.contains(&format!("line {line}")) && e.contains(why),
                "{e}"
            );
        }
        let missing = TruthList::open(Path::new("/no/such/folder")).expect_err("missing");
        assert!(
            missing
                .to_string()
                .contains("/no/such/folder/timestamps.txt"),
            "{missing}"
        );
    }
}
