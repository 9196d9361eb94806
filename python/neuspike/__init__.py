"""neuspike for Python: the library on numpy arrays, and the messages and node protocol of graphs.

The library (the native module ``neuspike._native``, built by ``pip install ./python``), every
kernel run by neuspike's Rust crates with the GIL released:

- files: :func:`read_spikes`, :class:`SpikeReader`, :func:`write_spikes` (PKU ``.dat``);
  :func:`read_events`, :class:`EventReader`, :func:`write_events` (text, Prophesee RAW and DAT,
  AEDAT 4); :func:`read_aps_frames`, :class:`ApsFrameReader` (AEDAT 4 frames); :func:`read_truth`
  (ground-truth folders); :func:`info` (any recording summarised);
- values: :class:`Spikes` (bit-packed planes and their clock), :class:`Events` (four columns);
- :func:`simulate`: both cameras on one scene, with ground truth, deterministic for a seed;
  :func:`frames_to_events`: the DVS on the user's frames, as v2e;
- :class:`Samples`: training samples made on demand, each deterministic in its index
  (:mod:`neuspike.data` makes them a PyTorch dataset);
- representations: :func:`tfp`, :func:`tfi`, :func:`isi`, :func:`tfstp`,
  :func:`spike_representation`, :func:`event_count`, :func:`event_integration`,
  :func:`voxel_grid`, :func:`event_stack`, :func:`time_surface`;
- a whole recording through the stages: :func:`represent`; reconstruction: :func:`reconstruct` (every method: classical, physics fusion, the networks,
  ``auto``) and :func:`run_graph` (a graph's stages as one in-process chain);
- metrics: :func:`psnr`, :func:`psnr_after_gain`, :func:`gain`, :func:`ssim`, :func:`entropy_2d`;
- :func:`set_threads`; errors: :class:`Error` and its kinds :class:`FormatError`,
  :class:`ConfigError`, :class:`InputError`.

The messages and node protocol (pure Python: pyarrow, numpy; dora-rs to run a node):

- :mod:`neuspike.messages`: Frame, Representation, SpikeChunk, EventBatch, Credit, end-of-stream
  markers; the layouts, header keys and errors of the Rust crate ``neuspike-schemas``.
- :mod:`neuspike.ipc`: a message as Arrow IPC bytes, as neuspike publishes it on zenoh.
- :mod:`neuspike.link`: a node's link to its graph (order, loss counting, credits, markers).
"""

try:
    from ._native import (
        FEATURES,
        ApsFrameReader,
        ConfigError,
        Error,
        EventReader,
        Events,
        FormatError,
        InputError,
        Samples,
        Simulation,
        SpikeReader,
        Spikes,
        entropy_2d,
        event_count,
        event_integration,
        event_stack,
        frames_to_events,
        gain,
        info,
        isi,
        models,
        psnr,
        psnr_after_gain,
        read_aps_frames,
        read_events,
        read_spikes,
        read_truth,
        reconstruct,
        represent,
        run_graph,
        scenes,
        set_threads,
        simulate,
        spike_representation,
        ssim,
        tfi,
        tfp,
        tfstp,
        threads,
        time_surface,
        voxel_grid,
        write_events,
        write_spikes,
    )

    NATIVE = True
except ImportError as _missing:  # the sources without the build: messages and nodes only
    NATIVE = False
    _why = str(_missing)

    def __getattr__(name):
        raise AttributeError(
            f"neuspike.{name} is in the native module, which this copy lacks ({_why}): "
            "install the package with `pip install ./python` (it builds with Rust)"
        )

from .ipc import IpcError, decode, encode
from .link import Link
from .messages import (
    VERSION,
    Credit,
    EventBatch,
    Frame,
    Representation,
    SchemaError,
    SpikeChunk,
    end_of_stream,
    is_end_of_stream,
)

__all__ = [
    "NATIVE",
    "VERSION",
    "Credit",
    "EventBatch",
    "Frame",
    "IpcError",
    "Link",
    "Representation",
    "SchemaError",
    "SpikeChunk",
    "decode",
    "encode",
    "end_of_stream",
    "is_end_of_stream",
]
if NATIVE:
    __all__ += [
        "FEATURES",
        "ApsFrameReader",
        "ConfigError",
        "Error",
        "EventReader",
        "Events",
        "FormatError",
        "InputError",
        "Samples",
        "Simulation",
        "SpikeReader",
        "Spikes",
        "entropy_2d",
        "event_count",
        "event_integration",
        "event_stack",
        "frames_to_events",
        "gain",
        "info",
        "isi",
        "models",
        "psnr",
        "psnr_after_gain",
        "read_aps_frames",
        "read_events",
        "read_spikes",
        "read_truth",
        "reconstruct",
        "represent",
        "run_graph",
        "scenes",
        "set_threads",
        "simulate",
        "spike_representation",
        "ssim",
        "tfi",
        "tfp",
        "tfstp",
        "threads",
        "time_surface",
        "voxel_grid",
        "write_events",
        "write_spikes",
    ]
