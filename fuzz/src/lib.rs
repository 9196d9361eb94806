//! The checks of the fuzz targets, as plain functions ([`formats`], [`graph`], [`ipc`],
//! [`policy`], [`ros2`], [`scene`]): the targets call them on what libFuzzer makes, and the
//! regular tests replay the committed corpus (`corpus-min/`) through them without libFuzzer
//! (`formats/tests/corpus.rs`, `pipeline/tests/corpus.rs`, `schemas/tests/corpus.rs`,
//! `scene/tests/corpus.rs`, `stages/event-camera/tests/corpus.rs`,
//! `stages/reconstruction/tests/corpus.rs`).

pub mod formats;
pub mod graph;
pub mod ipc;
pub mod policy;
pub mod ros2;
pub mod scene;

pub use formats::{drain, options};
