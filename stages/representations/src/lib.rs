//! Representations of spike planes and events for neuspike's reconstruction nodes.
//!
//! Pure kernels, no dora: the `neuspike-represent` node decodes its Arrow inputs, hands each
//! window to a [`Representer`] (every kind from one window, the dispatch `neuspike dataset` uses
//! too) and sends the result. Definitions follow `docs/definitions.md` (after NeuSpike-Net, ICCV 2021):
//!
//! | kernel | produces |
//! |---|---|
//! | [`tfp_into`] | TFP: firing rate per tick over the planes given, `[H, W]` in `[0, 1]` |
//! | [`isi_into`] | ISI in ticks at a reference plane, `[H, W]` `>= 1`, plus a validity mask |
//! | [`tfi_into`] | TFI: `1 / ISI`, `[H, W]` in `(0, 1]` |
//! | [`spike_representation_into`] | NeuSpike-Net spike tensor: 1/ISI channel + `n - 1` raw planes |
//! | [`StpFilter`] | TFSTP: firing rate per tick from short-term plasticity synapses, across windows |
//! | [`event_integration_into`] | event integration (paper Eq. 8), one channel per instant |
//! | [`event_count_into`] | signed event count per pixel |
//! | [`voxel_grid_into`] | E2VID voxel grid: `B` bins, linear in time, optionally normalised |
//! | [`event_stack_into`] | event stacking (SBT): signed count per pixel in each of `B` bins |
//! | [`time_surface_into`] | time surface `exp(-(t_ref - t_last) / tau)`, ON and OFF channels |
//! | [`window_stats`] | a window's light, motion, texture, dynamic range and events, for choosing a method |
//!
//! Conventions: spike planes are `ArrayView3<u8>` `[N, H, W]` (nonzero = spike), events an
//! [`EventSlice`] sorted by time. Kernels never modify their inputs, write every element of their
//! destination, and never write NaN or infinity. Each has a scalar `*_reference` oracle that the
//! tests compare the fast path against.
#![deny(missing_docs)]

mod error;
mod event;
mod spike;
mod stage;
mod stats;
mod stp;
mod surface;
#[cfg(test)]
mod testing;
mod voxel;
mod window;

#[cfg(test)]
mod extremes;

pub use error::RepresentError;
pub use event::{
    EventSlice, event_count_into, event_count_reference, event_integration_into,
    event_integration_reference, integration_instants,
};
pub use spike::{
    MAX_PLANES, MIN_ELEMENTS_FOR_RAYON, ROWS_PER_TASK, isi_into, isi_packed_into,
    isi_packed_into_with, isi_reference, raw_block_start, spike_representation_into,
    spike_representation_packed_into, spike_representation_parts, spike_representation_reference,
    tfi_into, tfi_reference, tfp_into, tfp_packed_into, tfp_packed_into_with, tfp_reference,
};
pub use stage::RepresentStage;
pub use stats::{
    BLOCK, CELL, WindowStats, central_window_stats, choice_stats, window_stats,
    window_stats_reference,
};
pub use stp::{StpFilter, StpParams};
pub use surface::{TIME_SURFACE_CHANNELS, time_surface_into, time_surface_reference};
pub use voxel::{
    VoxelNorm, event_stack_into, event_stack_reference, voxel_grid_into, voxel_grid_reference,
};
pub use window::{MAX_CHANNELS, RepresentConfig, Representer};
