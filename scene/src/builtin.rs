//! The scenes shipped in `graphs/scenes/`, embedded at build time.

/// Builtin names, in the order documented.
pub(crate) const NAMES: &[&str] = &[
    "bright-static",
    "bright-slow",
    "bright-fast",
    "dark-slow",
    "hdr-pan",
];

macro_rules! scene_file {
    ($name:literal) => {
        include_str!(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../graphs/scenes/",
            $name,
            ".yml"
        ))
    };
}

/// The YAML of builtin `name`, if it is one.
pub(crate) fn yaml(name: &str) -> Option<&'static str> {
    Some(match name {
        "bright-static" => scene_file!("bright-static"),
        "bright-slow" => scene_file!("bright-slow"),
        "bright-fast" => scene_file!("bright-fast"),
        "dark-slow" => scene_file!("dark-slow"),
        "hdr-pan" => scene_file!("hdr-pan"),
        _ => return None,
    })
}
