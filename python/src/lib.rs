//! `neuspike._native`: neuspike's library for Python, on numpy arrays.
//!
//! The pure Rust crates do the work (`neuspike-formats`, the camera simulators,
//! `neuspike-representations`, `neuspike-metrics`); this crate only converts. Every kernel runs
//! with the GIL released, on the package's own rayon pool ([`threads`]). Arrays going out are
//! the Rust vectors themselves, handed to numpy without a copy; arrays coming in are read in
//! place where they are contiguous and of the kernel's type.
//!
//! Errors are `neuspike.Error` and one subclass per kind, each carrying the one-line message the
//! Rust side gives ([`errors`]).

// A Python function's keyword arguments are the Rust function's parameters.
#![allow(clippy::too_many_arguments)]

mod dataset;
mod errors;
mod io;
mod kernels;
mod pipeline;
mod settings;
mod simulate;
mod threads;
mod values;

use pyo3::prelude::*;

/// The module. Its classes and functions are re-exported by `neuspike/__init__.py`, which
/// documents the package.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<errors::Error>())?;
    m.add("FormatError", py.get_type::<errors::FormatError>())?;
    m.add("ConfigError", py.get_type::<errors::ConfigError>())?;
    m.add("InputError", py.get_type::<errors::InputError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // The optional parts this build has.
    let features: Vec<&str> = [("hdf5", cfg!(feature = "hdf5"))]
        .into_iter()
        .filter_map(|(f, on)| on.then_some(f))
        .collect();
    m.add("FEATURES", features)?;

    m.add_function(wrap_pyfunction!(threads::set_threads, m)?)?;
    m.add_function(wrap_pyfunction!(threads::threads, m)?)?;

    m.add_class::<values::Spikes>()?;
    m.add_class::<values::Events>()?;

    m.add_function(wrap_pyfunction!(io::read_spikes, m)?)?;
    m.add_class::<io::SpikeReader>()?;
    m.add_function(wrap_pyfunction!(io::write_spikes, m)?)?;
    m.add_function(wrap_pyfunction!(io::read_events, m)?)?;
    m.add_class::<io::EventReader>()?;
    m.add_function(wrap_pyfunction!(io::write_events, m)?)?;
    m.add_function(wrap_pyfunction!(io::read_aps_frames, m)?)?;
    m.add_class::<io::ApsFrameReader>()?;
    m.add_function(wrap_pyfunction!(io::info, m)?)?;
    m.add_function(wrap_pyfunction!(io::read_truth, m)?)?;

    m.add_function(wrap_pyfunction!(kernels::tfp, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::isi, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::tfi, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::spike_representation, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::tfstp, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::event_count, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::event_integration, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::voxel_grid, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::event_stack, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::time_surface, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::psnr, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::psnr_after_gain, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::gain, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::ssim, m)?)?;
    m.add_function(wrap_pyfunction!(kernels::entropy_2d, m)?)?;

    m.add_function(wrap_pyfunction!(simulate::simulate, m)?)?;
    m.add_class::<simulate::Simulation>()?;
    m.add_function(wrap_pyfunction!(simulate::scenes, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::frames_to_events, m)?)?;
    m.add_class::<dataset::Samples>()?;
    m.add_function(wrap_pyfunction!(pipeline::reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(pipeline::run_graph, m)?)?;
    m.add_function(wrap_pyfunction!(pipeline::represent, m)?)?;
    m.add_function(wrap_pyfunction!(pipeline::models, m)?)?;
    Ok(())
}
