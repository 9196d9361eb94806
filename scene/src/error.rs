//! Errors of loading a scene. Each names the source (`origin`), the field and the value.

use std::path::PathBuf;

/// Why a scene could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file could not be read.
    #[error("scene {origin}: cannot read the file: {source}")]
    Read {
        /// The file.
        origin: String,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The YAML is malformed, has an unknown field or a value of the wrong type.
    /// `message` is serde_yaml's, which starts with the field path (e.g. `texture.kind: ...`).
    #[error("scene {origin}: {message}")]
    Parse {
        /// Where the YAML came from.
        origin: String,
        /// serde_yaml's message, with the field path and location.
        message: String,
    },
    /// A field holds a value out of range.
    #[error("scene {origin}: field {field}: invalid value {value} ({reason})")]
    Invalid {
        /// Where the scene came from.
        origin: String,
        /// Dotted path of the field, e.g. `texture.min`.
        field: String,
        /// The offending value as written.
        value: String,
        /// What the value must be.
        reason: String,
    },
    /// A field is required in this context but absent.
    #[error("scene {origin}: field {field}: missing ({reason})")]
    Missing {
        /// Where the scene came from.
        origin: String,
        /// Dotted path of the field.
        field: String,
        /// When it is required.
        reason: String,
    },
    /// A texture parameter that the chosen kind does not use.
    #[error("scene {origin}: field {field}: not used by texture.kind {kind} (only by {used_by})")]
    Unused {
        /// Where the scene came from.
        origin: String,
        /// Dotted path of the field.
        field: String,
        /// The texture kind in the scene.
        kind: String,
        /// The kinds that use the field.
        used_by: String,
    },
    /// Fields that exclude each other.
    #[error("scene {origin}: fields {fields}: {reason}")]
    Conflict {
        /// Where the scene came from.
        origin: String,
        /// The fields and their values.
        fields: String,
        /// What is allowed.
        reason: String,
    },
    /// The PNG texture file could not be read.
    #[error("scene {origin}: field texture.path: cannot read {value:?} (resolved to {}): {source}", path.display())]
    TextureRead {
        /// Where the scene came from.
        origin: String,
        /// The path as written in the scene.
        value: String,
        /// The path after resolving against the scene's folder.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The PNG texture file could not be decoded, or has an unusable size.
    #[error("scene {origin}: field texture.path: cannot use {value:?} as a texture: {reason}")]
    TextureDecode {
        /// Where the scene came from.
        origin: String,
        /// The path as written in the scene.
        value: String,
        /// The decoder's message or the size problem.
        reason: String,
    },
    /// `Scene::builtin` was given a name that is not a builtin scene.
    #[error("unknown builtin scene {name:?} (expected one of {expected})")]
    UnknownBuiltin {
        /// The name asked for.
        name: String,
        /// The builtin names, comma separated.
        expected: String,
    },
}
