//! Ground truth recorded beside a spike file: a folder of luminance PNGs listed in
//! `timestamps.txt` (`plane t_ns file` per line, `#` comments), as `neuspike simulate` writes it.
//! The list is read and checked when the folder is opened; each PNG is read when its plane is
//! played, so memory holds one frame.

use std::path::{Path, PathBuf};

use ndarray::Array2;

/// A ground-truth folder: the planes that have a frame, in order, and their files.
#[derive(Clone, Debug)]
pub struct TruthFolder {
    /// `timestamps.txt`, as errors name it.
    pub list: PathBuf,
    /// `(plane, PNG path)`, planes strictly increasing.
    pub frames: Vec<(u64, PathBuf)>,
}

impl TruthFolder {
    /// Reads `dir/timestamps.txt`. Errors name the file, the line and the value: a line that is
    /// not `plane t_ns file`, a plane that does not increase, a file name leaving the folder.
    pub fn open(dir: &Path) -> Result<Self, String> {
        let list = dir.join("timestamps.txt");
        let text = std::fs::read_to_string(&list)
            .map_err(|e| format!("{}: cannot read the ground-truth list: {e}", list.display()))?;
        let mut frames: Vec<(u64, PathBuf)> = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let bad = |why: &str| format!("{} line {}: `{line}`: {why}", list.display(), i + 1);
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
        Ok(TruthFolder { list, frames })
    }

    /// The frames whose plane lies in `planes`.
    pub fn in_range(&self, planes: std::ops::Range<u64>) -> &[(u64, PathBuf)] {
        let a = self.frames.partition_point(|f| f.0 < planes.start);
        let b = self.frames.partition_point(|f| f.0 < planes.end);
        &self.frames[a..b]
    }
}

/// A ground-truth PNG as luminance in `[0, 1]` (8- or 16-bit grey, or colour taken as its
/// luma), checked against the sensor size `(height, width)`.
pub fn read_truth_png(path: &Path, height: usize, width: usize) -> Result<Array2<f32>, String> {
    let img = image::open(path)
        .map_err(|e| {
            format!(
                "{}: cannot read the ground-truth frame: {e}",
                path.display()
            )
        })?
        .to_luma16();
    let (w, h) = (img.width() as usize, img.height() as usize);
    if (h, w) != (height, width) {
        return Err(format!(
            "{}: the ground-truth frame is {w}x{h}, the spike planes {width}x{height}",
            path.display()
        ));
    }
    let data: Vec<f32> = img
        .into_raw()
        .into_iter()
        .map(|v| f32::from(v) / 65535.0)
        .collect();
    Array2::from_shape_vec((h, w), data).map_err(|e| format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn folder(list: &str) -> (tempfile::TempDir, Result<TruthFolder, String>) {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(dir.path().join("timestamps.txt"), list).expect("write");
        let t = TruthFolder::open(dir.path());
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
    fn bad_lists_name_the_line_and_the_value() {
        for (list, line, why) in [
            ("0 0\n", 1, "three fields"),
            ("x 0 a.png\n", 1, "plane"),
            ("0 0 a.png\n5 1.5 b.png\n", 2, "t_ns"),
            ("0 0 ../a.png\n", 1, "inside the folder"),
            ("20 0 a.png\n20 0 b.png\n", 2, "increase"),
        ] {
            let (_dir, t) = folder(list);
            let e = t.expect_err(list);
            assert!(
                e.contains(&format!("line {line}")) && e.contains(why),
                "{e}"
            );
        }
        let missing = TruthFolder::open(Path::new("/no/such/folder")).expect_err("missing");
        assert!(
            missing.contains("/no/such/folder/timestamps.txt"),
            "{missing}"
        );
    }

    #[test]
    fn png_levels_and_size_are_checked() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("f.png");
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(3, 2, |x, _| {
            image::Luma([[0u16, 32768, 65535][x as usize]])
        });
        img.save(&p).expect("save");
        let f = read_truth_png(&p, 2, 3).expect("read");
        assert_eq!(f[[1, 0]], 0.0);
        assert_eq!(f[[0, 2]], 1.0);
        assert!((f[[0, 1]] - 0.5).abs() < 1e-4);
        let e = read_truth_png(&p, 3, 3).expect_err("wrong size");
        assert!(e.contains("3x2") && e.contains("3x3"), "{e}");
        let e = read_truth_png(&dir.path().join("none.png"), 2, 3).expect_err("missing");
        assert!(e.contains("none.png"), "{e}");
    }
}
