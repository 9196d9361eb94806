//! Small files written whole or not at all: the bytes go to a temporary file beside the target,
//! are synced to the disk, and the temporary file is renamed over the target, so a crash, a kill
//! or a full disk mid-write leaves the old file (or none), never a shorter one that reads as
//! whole. For manifests, summaries, tables and graphs; a stream (events, metrics rows) is
//! written as it is made instead, and marked complete by such a file written last.

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Writes `contents` to `path` atomically (see the module). On failure the temporary file is
/// removed (best effort) and `path` is as it was.
///
/// # Errors
/// The folder cannot be written, the disk is full, or the rename failed; the error names the
/// file.
pub fn write(path: &Path, contents: impl AsRef<[u8]>) -> io::Result<()> {
    let tmp = temporary(path);
    let result = (|| {
        let mut file = File::create(&tmp)?;
        file.write_all(contents.as_ref())?;
        file.sync_all()?;
        drop(file);
        fs::rename(&tmp, path)?;
        // The rename itself, on the disk: best effort (not every filesystem syncs a folder).
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty())
            && let Ok(d) = File::open(dir)
        {
            let _ = d.sync_all();
        }
        Ok(())
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(|e: io::Error| io::Error::new(e.kind(), format!("{}: {e}", path.display())))
}

/// `<path>.<pid>.tmp`, beside `path`: two processes writing one file do not share it.
fn temporary(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".{}.tmp", std::process::id()));
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_is_replaced_whole_and_nothing_is_left_beside_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("recording.yml");
        write(&path, "first: 1\n").expect("write");
        write(&path, "second: 2\n").expect("rewrite");
        assert_eq!(fs::read_to_string(&path).expect("read"), "second: 2\n");
        let names: Vec<_> = fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(names, ["recording.yml"]);
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_and_names_the_path() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("absent").join("summary.md");
        let e = write(&path, "x").expect_err("no folder").to_string();
        assert!(e.contains("absent/summary.md"), "{e}");
        // A folder in the way of the rename: the write fails, nothing is left behind.
        let taken = dir.path().join("taken");
        fs::create_dir(&taken).expect("mkdir");
        fs::write(taken.join("inside"), "keep").expect("write");
        assert!(write(&taken, "x").is_err());
        assert_eq!(fs::read_dir(dir.path()).expect("list").count(), 1);
    }
}
