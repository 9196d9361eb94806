//! The `neuspike` program's library: running graphs on an embedded dora daemon, and writing
//! simulated recordings.
//!
//! The binary (`src/main.rs`) is the command line; the end-to-end tests in `tests/` call
//! [`graph::run`] directly.
#![deny(missing_docs)]

pub mod aps_check;
pub mod bench_live;
pub mod bench_model;
pub mod calibrate;
pub mod cluster;
pub mod frames_to_events;
pub mod frames_to_spikes;
pub mod graph;
pub mod held_out;
pub mod in_process;
pub mod memory;
pub mod models;
pub mod node;
pub mod publish_file;
pub mod reconstruct;
pub mod record;
pub mod rig;
pub mod soak;
pub mod trade;

pub mod demo;
