//! The networks and the `--method auto` policy shipped in `models/`, built into the program, so
//! that an installed `neuspike` finds them wherever it runs.
//!
//! A path a user names is taken as given. The defaults (`models`, `models/policy.yml`) are
//! relative to the current folder: where that has no such file (a program run outside its
//! source checkout), the built-in copy is used, written once into the user's cache folder
//! (`$XDG_CACHE_HOME/neuspike/` or `~/.cache/neuspike/`, else the temporary folder).

use std::path::{Component, Path, PathBuf};

use eyre::WrapErr;

/// Every shipped file, by name, with its bytes.
const SHIPPED: &[(&str, &[u8])] = &[
    ("policy.yml", include_bytes!("../models/policy.yml")),
    (
        "neuspike-event-8.onnx",
        include_bytes!("../models/neuspike-event-8.onnx"),
    ),
    (
        "neuspike-fused-8.onnx",
        include_bytes!("../models/neuspike-fused-8.onnx"),
    ),
    (
        "neuspike-fused-8-lite.onnx",
        include_bytes!("../models/neuspike-fused-8-lite.onnx"),
    ),
    (
        "neuspike-fused-8-anycam.onnx",
        include_bytes!("../models/neuspike-fused-8-anycam.onnx"),
    ),
    (
        "neuspike-fused-16.onnx",
        include_bytes!("../models/neuspike-fused-16.onnx"),
    ),
    (
        "neuspike-fused-24.onnx",
        include_bytes!("../models/neuspike-fused-24.onnx"),
    ),
    (
        "neuspike-spike-4-lite.onnx",
        include_bytes!("../models/neuspike-spike-4-lite.onnx"),
    ),
    (
        "neuspike-spike-8.onnx",
        include_bytes!("../models/neuspike-spike-8.onnx"),
    ),
    (
        "neuspike-spike-8-anycam.onnx",
        include_bytes!("../models/neuspike-spike-8-anycam.onnx"),
    ),
    (
        "neuspike-spike-8-lite.onnx",
        include_bytes!("../models/neuspike-spike-8-lite.onnx"),
    ),
    (
        "neuspike-spike-8-video.onnx",
        include_bytes!("../models/neuspike-spike-8-video.onnx"),
    ),
];

/// The user's cache folder: `$XDG_CACHE_HOME`, else `~/.cache`, else the temporary folder.
fn cache_base() -> PathBuf {
    std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(std::env::temp_dir)
}

/// The built-in models as a folder under the user's cache folder ([`write_shipped`]).
///
/// # Errors
/// The cache folder cannot be written.
pub fn shipped_dir() -> eyre::Result<PathBuf> {
    write_shipped(&cache_base())
}

/// Writes the built-in models into a folder under `base`, one per program version and content
/// (two versions never share files), each file through a temporary name and a rename so that a
/// file there is whole; a file already there whole is kept. Returns the folder.
///
/// # Errors
/// The folder cannot be written.
pub fn write_shipped(base: &Path) -> eyre::Result<PathBuf> {
    let bytes: usize = SHIPPED.iter().map(|(_, b)| b.len()).sum();
    let dir = base
        .join("neuspike")
        .join(format!("models-{}-{bytes:x}", env!("CARGO_PKG_VERSION")));
    std::fs::create_dir_all(&dir)
        .wrap_err_with(|| format!("cannot create {} for the built-in models", dir.display()))?;
    for (name, bytes) in SHIPPED {
        let path = dir.join(name);
        if std::fs::metadata(&path).is_ok_and(|m| m.len() == bytes.len() as u64) {
            continue;
        }
        let tmp = dir.join(format!("{name}.tmp-{}", std::process::id()));
        std::fs::write(&tmp, bytes)
            .and_then(|()| std::fs::rename(&tmp, &path))
            .wrap_err_with(|| format!("cannot write the built-in model {}", path.display()))?;
    }
    Ok(dir)
}

/// `path` when it exists; else, for a relative path under `models/` (the defaults), the built-in
/// copy of that file or folder when there is one; else `path` (whose reader names it).
pub fn or_shipped(path: &Path) -> PathBuf {
    if path.exists() {
        return path.to_path_buf();
    }
    let mut parts = path.components();
    if parts.next() != Some(Component::Normal("models".as_ref())) {
        return path.to_path_buf();
    }
    let rest: PathBuf = parts.collect();
    let shipped =
        rest.as_os_str().is_empty() || SHIPPED.iter().any(|(name, _)| rest == Path::new(name));
    if !shipped {
        return path.to_path_buf();
    }
    match shipped_dir() {
        Ok(dir) => dir.join(rest),
        Err(e) => {
            tracing::warn!("{e:#}");
            path.to_path_buf()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_shipped_network_and_the_policy_are_built_in() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
        let mut files: Vec<String> = std::fs::read_dir(&dir)
            .expect("models/")
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".onnx") || n == "policy.yml")
            .collect();
        files.sort();
        let mut built_in: Vec<String> = SHIPPED.iter().map(|(n, _)| n.to_string()).collect();
        built_in.sort();
        assert_eq!(files, built_in);
        for (name, bytes) in SHIPPED {
            assert_eq!(
                std::fs::read(dir.join(name)).expect("file"),
                *bytes,
                "{name}"
            );
        }
    }

    #[test]
    fn the_built_in_copy_is_written_once_whole_and_a_named_path_stays() {
        let cache = tempfile::tempdir().expect("tempdir");
        let dir = write_shipped(cache.path()).expect("written");
        assert!(dir.starts_with(cache.path()));
        for (name, bytes) in SHIPPED {
            assert_eq!(
                std::fs::read(dir.join(name)).expect("file"),
                *bytes,
                "{name}"
            );
        }
        // A second time keeps what is there and leaves no temporary file.
        assert_eq!(write_shipped(cache.path()).expect("again"), dir);
        let names = std::fs::read_dir(&dir).expect("dir").count();
        assert_eq!(names, SHIPPED.len());
        let named = Path::new("elsewhere/policy.yml");
        assert_eq!(or_shipped(named), named);
        let unknown = Path::new("models/none.onnx");
        assert_eq!(or_shipped(unknown), unknown);
        // Run from the repository root, the checkout's own files are taken.
        let here = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/policy.yml");
        assert_eq!(or_shipped(&here), here);
    }
}
