//! Where a source restarted by dora (a node's `restart_policy`) picks up: the wall time of its
//! first start, kept in a small file named after the dataflow and the node, so that the new
//! process knows how far its camera has gone meanwhile.
//!
//! A live source resumes at the camera's position now and numbers its messages as if it had
//! sent everything before: the planes of the time it was down are a gap in the sequence numbers,
//! which its consumers count (and return the credits of). A source not paced on the camera's clock
//! cannot tell where it stopped and refuses to resume.

use std::path::PathBuf;

use dora_node_api::DoraNode;
use eyre::WrapErr;

use crate::unix_now_ns;

/// A source's first start, found again after a restart.
#[derive(Debug)]
pub struct Resume {
    path: PathBuf,
    /// Wall time of the first start of this node in this dataflow, ns since the epoch.
    pub first_start_unix_ns: i64,
    /// Whether this process is a restart (the first start was an earlier process's).
    pub restarted: bool,
}

impl Resume {
    /// The file for `node` of its dataflow, in the system's temporary folder.
    pub fn for_node(node: &DoraNode) -> eyre::Result<Self> {
        let name = format!("neuspike-start-{}-{}", node.dataflow_id(), node.id());
        Self::at(std::env::temp_dir().join(name))
    }

    /// The first start recorded at `path`, or now (recorded there) when there is none. A file
    /// that does not hold a time is taken as absent and rewritten.
    pub fn at(path: PathBuf) -> eyre::Result<Self> {
        let earlier = std::fs::read_to_string(&path)
            .ok()
            .and_then(|s| s.trim().parse::<i64>().ok());
        if let Some(first_start_unix_ns) = earlier {
            return Ok(Resume {
                path,
                first_start_unix_ns,
                restarted: true,
            });
        }
        let now = unix_now_ns();
        // Through a temporary file and a rename: a restarted node never reads half a time.
        let tmp = path.with_extension(format!("{}.tmp", std::process::id()));
        std::fs::write(&tmp, now.to_string())
            .and_then(|()| std::fs::rename(&tmp, &path))
            .wrap_err_with(|| format!("cannot write the start time to {}", path.display()))?;
        Ok(Resume {
            path,
            first_start_unix_ns: now,
            restarted: false,
        })
    }

    /// The stream ended: the file goes (a later start of the node is a new stream).
    pub fn finished(self) {
        if let Err(e) = std::fs::remove_file(&self.path) {
            tracing::warn!("cannot remove {}: {e}", self.path.display());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_start_is_kept_for_a_restart_and_forgotten_when_the_stream_ends() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("start");
        let first = Resume::at(path.clone()).expect("first");
        assert!(!first.restarted);
        let again = Resume::at(path.clone()).expect("again");
        assert!(again.restarted);
        assert_eq!(again.first_start_unix_ns, first.first_start_unix_ns);
        again.finished();
        assert!(!path.exists());
        std::fs::write(&path, "not a time").expect("write");
        let fresh = Resume::at(path.clone()).expect("fresh");
        assert!(!fresh.restarted && fresh.first_start_unix_ns > 0);
    }
}
