"""Type stubs of neuspike's native module (re-exported by ``neuspike``)."""

import os
import pathlib
from typing import Iterator, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str
FEATURES: list[str]
"""The optional parts this build has (``"hdf5"``)."""

PathLike = Union[str, os.PathLike]
Planes = npt.NDArray[Union[np.uint8, np.bool_]]
SpikesLike = Union["Spikes", Planes]
Frame = npt.ArrayLike
Setting = Union[bool, int, float, str]

class Error(Exception):
    """Every error neuspike raises: the one-line message the Rust side gives."""

class FormatError(Error):
    """A file that cannot be opened, read or written: names the file, the offset or line, the value."""

class ConfigError(Error):
    """A setting refused (a camera or scene argument, a thread count): names the setting and value."""

class InputError(Error):
    """Arrays a kernel refuses (a shape, an index, an unsorted event): names the argument and value."""

def set_threads(n: int) -> None:
    """Sets how many threads the kernels use (0: one per core, the default)."""

def threads() -> int:
    """How many threads the kernels use."""

class Spikes:
    """Spike planes, bit-packed as the camera sends them, with their clock.

    ``packed`` is ``uint8 [N, ceil(H * W / 8)]``, pixel ``y * W + x`` at bit ``i % 8`` (least
    significant first) of byte ``i // 8``: ``np.unpackbits(packed, axis=1, bitorder="little")``.
    Plane ``k`` is stamped ``t_first_ns + k * plane_period_ns``.
    """

    width: int
    height: int
    first_plane: int
    t_first_ns: int
    plane_period_ns: int
    lum_per_rate: Optional[float]
    def __init__(
        self,
        packed: npt.NDArray[np.uint8],
        width: int,
        height: int,
        *,
        t_first_ns: int = 0,
        plane_period_ns: int = 50_000,
        first_plane: int = 0,
        lum_per_rate: Optional[float] = None,
    ) -> None:
        """Wraps packed planes (read in place when C-contiguous ``uint8``)."""
    @staticmethod
    def from_planes(
        planes: Planes,
        *,
        t_first_ns: int = 0,
        plane_period_ns: int = 50_000,
        first_plane: int = 0,
        lum_per_rate: Optional[float] = None,
    ) -> "Spikes":
        """Packs unpacked planes ``[N, H, W]`` (``uint8`` or ``bool``, nonzero = spike)."""
    @property
    def packed(self) -> npt.NDArray[np.uint8]:
        """The packed planes (the array itself, not a copy)."""
    @property
    def n_planes(self) -> int: ...
    def __len__(self) -> int: ...
    def unpack(self) -> npt.NDArray[np.uint8]:
        """The planes ``uint8 [N, H, W]``, 1 where a pixel fired."""
    def plane_times_ns(self) -> npt.NDArray[np.int64]:
        """Each plane's time stamp, ns."""
    def window(self, start: int, stop: int) -> "Spikes":
        """Planes ``start:stop``, sharing this value's memory."""

class Events:
    """Events as four columns with their sensor, covering ``[t_start_ns, t_end_ns)``."""

    width: int
    height: int
    t_start_ns: int
    t_end_ns: int
    def __init__(
        self,
        t_ns: npt.ArrayLike,
        x: npt.ArrayLike,
        y: npt.ArrayLike,
        polarity: npt.ArrayLike,
        width: int,
        height: int,
        *,
        t_start_ns: Optional[int] = None,
        t_end_ns: Optional[int] = None,
    ) -> None:
        """Columns as ``int64``, ``uint16``, ``uint16``, ``int8`` (read in place when they are)."""
    @staticmethod
    def from_structured(
        array: np.ndarray,
        width: int,
        height: int,
        *,
        t_start_ns: Optional[int] = None,
        t_end_ns: Optional[int] = None,
    ) -> "Events":
        """From a structured array with fields ``t_ns``, ``x``, ``y``, ``polarity``."""
    def to_structured(self) -> np.ndarray:
        """One structured array (a copy)."""
    @property
    def t_ns(self) -> npt.NDArray[np.int64]: ...
    @property
    def x(self) -> npt.NDArray[np.uint16]: ...
    @property
    def y(self) -> npt.NDArray[np.uint16]: ...
    @property
    def polarity(self) -> npt.NDArray[np.int8]: ...
    def __len__(self) -> int: ...

def read_spikes(
    path: PathLike,
    *,
    width: int = 400,
    height: int = 250,
    head_columns: int = 0,
    plane_period_ns: int = 50_000,
    t_first_ns: int = 0,
    max_planes: Optional[int] = None,
) -> Spikes:
    """Reads a PKU spike ``.dat`` file whole (or its first ``max_planes``)."""

class SpikeReader(Iterator[Spikes]):
    """A PKU spike ``.dat`` file read as it is iterated, ``chunk_planes`` planes at a time."""

    planes_read: int
    def __init__(
        self,
        path: PathLike,
        *,
        chunk_planes: int = 1000,
        width: int = 400,
        height: int = 250,
        head_columns: int = 0,
        plane_period_ns: int = 50_000,
        t_first_ns: int = 0,
    ) -> None: ...
    def __iter__(self) -> "SpikeReader": ...
    def __next__(self) -> Spikes: ...

def write_spikes(path: PathLike, spikes: SpikesLike, *, head_columns: int = 0) -> int:
    """Writes planes as a PKU ``.dat`` file; returns the planes written."""

def read_events(
    path: PathLike,
    *,
    width: Optional[int] = None,
    height: Optional[int] = None,
    max_events: Optional[int] = None,
) -> Events:
    """Reads any event file neuspike reads (text, Prophesee RAW and DAT, AEDAT 4) whole."""

class EventReader(Iterator[Events]):
    """An event file read as it is iterated, ``chunk_events`` events at a time."""

    resolution: Tuple[int, int]
    def __init__(
        self,
        path: PathLike,
        *,
        chunk_events: int = 1 << 20,
        width: Optional[int] = None,
        height: Optional[int] = None,
    ) -> None: ...
    def __iter__(self) -> "EventReader": ...
    def __next__(self) -> Events: ...

def write_events(
    path: PathLike,
    events: Events,
    *,
    format: Optional[str] = None,
    aps: Optional[Tuple[Sequence[int], npt.ArrayLike]] = None,
) -> int:
    """Writes events (``.txt``, ``.raw`` EVT 3.0, ``"evt2"``, ``.dat``, ``.aedat4`` with optional
    APS frames ``aps=(t_ns, frames [K, H, W])``, ``.h5`` with the hdf5 feature); returns the count."""

def read_aps_frames(path: PathLike) -> Tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]:
    """An AEDAT 4 file's APS frames: times ``[K]`` ns and luminance ``[K, H, W]``."""

class ApsFrameReader(Iterator[Tuple[int, npt.NDArray[np.float32]]]):
    """An AEDAT 4 file's APS frames read as it is iterated: ``(t_ns, frame [H, W])``."""

    def __init__(self, path: PathLike) -> None: ...
    def __iter__(self) -> "ApsFrameReader": ...
    def __next__(self) -> Tuple[int, npt.NDArray[np.float32]]: ...

def info(
    path: PathLike,
    *,
    width: int = 400,
    height: int = 250,
    head_columns: int = 0,
    plane_period_ns: int = 50_000,
) -> dict:
    """Any recording summarised: ``kind``, ``format``, counts, times, and ``text``."""

def read_truth(path: PathLike) -> Tuple[npt.NDArray[np.uint64], npt.NDArray[np.float32]]:
    """A ground-truth folder (``timestamps.txt`` and PNGs): planes ``[K]`` and frames ``[K, H, W]``."""

def tfp(spikes: SpikesLike) -> npt.NDArray[np.float32]:
    """TFP: each pixel's firing rate per tick over the planes, ``[H, W]``."""

def isi(
    spikes: SpikesLike, ref: Optional[int] = None
) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """The inter-spike interval at plane ``ref`` (default the middle) and where it was measured."""

def tfi(spikes: SpikesLike, ref: Optional[int] = None) -> npt.NDArray[np.float32]:
    """TFI: ``1 / ISI`` at plane ``ref`` (default the middle), ``[H, W]``."""

def tfstp(
    spikes: SpikesLike,
    *,
    u0: float = 0.15,
    f: float = 0.15,
    tau_d_ticks: float = 1.0,
    tau_f_ticks: float = 10.0,
) -> npt.NDArray[np.float32]:
    """TFSTP: each pixel's firing rate after the planes, from short-term plasticity synapses."""

def spike_representation(
    spikes: SpikesLike, ref: Optional[int] = None, channels: int = 32
) -> npt.NDArray[np.float32]:
    """NeuSpike-Net's spike tensor ``[channels, H, W]``: the TFI, then the planes around ``ref``."""

def event_count(events: Events) -> npt.NDArray[np.float32]:
    """The signed event count per pixel, ``[H, W]``."""

def event_integration(
    events: Events, t0_ns: int, instants_ns: Sequence[int], tau_ns: float
) -> npt.NDArray[np.float32]:
    """NeuSpike-Net's event integration (Eq. 8) at each instant, ``[K, H, W]``."""

def voxel_grid(events: Events, bins: int, *, normalise: bool = False) -> npt.NDArray[np.float32]:
    """E2VID's voxel grid, ``[bins, H, W]``."""

def event_stack(events: Events, bins: int) -> npt.NDArray[np.float32]:
    """The event stack: signed counts in ``bins`` equal spans of time, ``[bins, H, W]``."""

def time_surface(events: Events, t_ref_ns: int, tau_ns: float) -> npt.NDArray[np.float32]:
    """The ON and OFF time surfaces at ``t_ref_ns``, ``[2, H, W]``."""

def psnr(x: Frame, gt: Frame) -> float:
    """PSNR in dB, data range 1; ``inf`` for identical frames."""

def psnr_after_gain(x: Frame, gt: Frame) -> float:
    """PSNR after the least-squares gain mapping ``x`` onto ``gt``."""

def gain(x: Frame, gt: Frame) -> float:
    """The least-squares gain ``sum(x gt) / sum(x x)`` (1 for an all-zero ``x``)."""

def ssim(x: Frame, gt: Frame) -> float:
    """SSIM, 11-tap Gaussian window of sigma 1.5, data range 1."""

def entropy_2d(x: Frame) -> float:
    """The 2D entropy in bits (grey level against its 3x3 neighbourhood mean)."""

class Simulation:
    """What :func:`simulate` made."""

    spikes: Optional[Spikes]
    events: Optional[Events]
    truth: npt.NDArray[np.float32]
    truth_planes: npt.NDArray[np.uint64]
    truth_t_ns: npt.NDArray[np.int64]

def scenes() -> list[str]:
    """The built-in scenes' names."""

def simulate(
    scene: str = "bright-slow",
    planes: int = 400,
    *,
    seed: int = 0,
    truth_every: int = 20,
    spikes: bool = True,
    events: bool = True,
    spike_camera: Optional[Mapping[str, Setting]] = None,
    event_camera: Optional[Mapping[str, Setting]] = None,
    frames: Optional[npt.ArrayLike] = None,
    frame_dt_ns: int = 1_000_000,
    light_scale: float = 1.0,
) -> Simulation:
    """Both cameras on one scene (a built-in, a YAML file, or ``frames``), deterministic for a seed."""

class Samples:
    """A simulated training or test set, its samples made on demand: ``samples[i]`` is sample
    ``i`` of ``neuspike dataset`` with the same options (their names without dashes), the spike
    camera drawn per sample unless ``randomise_camera=False``."""

    size: int
    channels: int
    randomise_camera: bool
    def __init__(self, split: str = "train", **options: Union[Setting, Sequence[str]]) -> None: ...
    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> dict:
        """``spike``, ``events`` ``[C, S, S]``; ``truth``, ``tfp``, ``tfi`` ``[S, S]``; ``also``;
        ``texture``, ``light``, ``speed_px_s``, ``angle_deg``, ``theta_on``, ``theta_off``,
        ``lum_per_rate``, ``event_count``, ``complex``."""
    def batch(self, indices: Sequence[int]) -> dict:  # negative indices count from the end
        """Samples made side by side and stacked: arrays ``[B, ...]``, scalars as arrays ``[B]``."""

def models() -> Optional[pathlib.Path]:
    """The shipped networks' folder (``$NEUSPIKE_MODELS``, else the building checkout's ``models/``)."""

def reconstruct(
    spikes: Spikes,
    events: Optional[Events] = None,
    *,
    method: str = "tfp",
    model: Optional[PathLike] = None,
    policy: Optional[PathLike] = None,
    window_planes: Optional[int] = None,
    stride_planes: int = 20,
    infer: str = "",
    lum_per_rate: Optional[float] = None,
) -> dict:
    """Frames by ``method`` (tfp, tfi, tfstp, hf, cf, fusion, learned, auto) through the graph's
    align, represent and infer stages in one process: ``frames [K, H, W]``, ``t_ref_ns``,
    ``compute_ns``, ``method``, and ``chosen`` for auto."""

def represent(
    spikes: Spikes,
    events: Optional[Events] = None,
    *,
    kinds: Sequence[str] = ("tfp",),
    window_planes: int = 33,
    stride_planes: int = 20,
    represent: str = "",
) -> dict:
    """Every window's representations of ``kinds`` through align and represent:
    ``{kind: [K, C, H, W], "t_ref_ns": [K]}``."""

def run_graph(
    graph: Union[PathLike, Mapping],
    *,
    set: Optional[Mapping[str, str]] = None,
    collect: Sequence[str] = (),
    cwd: Optional[PathLike] = None,
) -> dict:
    """A graph's nodes as one in-process chain; the messages of each ``node/output`` collected,
    and ``"stages"``, the run's table."""

def frames_to_events(
    frames: npt.ArrayLike,
    frame_dt_ns: int,
    *,
    light_scale: float = 1.0,
    event_camera: Optional[Mapping[str, Setting]] = None,
) -> Events:
    """The DVS pixel array on frames ``[T, H, W]`` a frame every ``frame_dt_ns``, as v2e."""
