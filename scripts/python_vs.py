"""neuspike's Python API against the Python tools researchers use today: speed and agreement.

Each pair runs the same operation on the same input in one process, neuspike's way and the other
tool's way, and prints one Markdown row: the input, neuspike's time on one thread (and on
`--threads`, an extra column), the other tool's time on one thread, the ratio (other /
neuspike, one thread each), and whether the two results are equal within the stated tolerance.
Where the definitions differ, one side's input or output is converted so that the two compute the
same thing, and the note column says how. Times are medians of at least `--reps` calls
(`time.perf_counter`; fast calls repeat to fill a quarter second) after one warm-up call;
loading the inputs is outside the timing.

| pair | operations | input |
|---|---|---|
| SpikeCV | TFP, TFI: one frame, every frame | the real Vidar recording, 33-plane windows |
| Spike-Zoo | TFP, TFI of one window; reading the `.dat` | the same |
| tonic | voxel grid, event stack | the real Prophesee EVT 2.0 recording |
| expelliarmus, evlib, aestream, dv-processing | reading events | it, and its EVT 3.0, DAT, AEDAT 4 copies |
| v2e | DVS events from frames (`ns.frames_to_events`) | a panned texture, 346x260, 100 frames of 1 ms |

SpikeCV's functions are in `spkProc/reconstruction/tfp.py` and `tfi.py`, Spike-Zoo's in
`archs/tfp/nets.py`, `archs/tfi/nets.py` and `utils/spike_utils.py`, tonic's are
`to_voxel_grid_numpy` and `to_frame_numpy`, v2e's is `v2ecore.emulator.EventEmulator`; the copies
of the event recording are written by `ns.write_events`.

A pair whose tool is missing, or that cannot read a format, is skipped with the reason printed
below the table. SpikeCV, Spike-Zoo and v2e are not on PyPI: the script imports their modules
from checkouts you give it, by file (their packages' `__init__` pull in much more than these
functions need), and none of their code is copied here. SpikeCV is Apache-2.0, Spike-Zoo and v2e
MIT.

Install (a virtual environment keeps these tools out of your system Python; neuspike from its
wheel, `python3 -m maturin build --release --manifest-path python/Cargo.toml`, or with
`pip install ./python` where Rust is installed):

    python3 -m venv ~/pyvs
    ~/pyvs/bin/pip install target/wheels/neuspike-*.whl     # or: ~/pyvs/bin/pip install ./python
    ~/pyvs/bin/pip install numpy tonic expelliarmus evlib aestream dv-processing
    ~/pyvs/bin/pip install torch opencv-python-headless imageio      # SpikeCV, Spike-Zoo, v2e
    ~/pyvs/bin/pip install h5py screeninfo engineering-notation easygui   # v2e's imports
    git clone https://github.com/Zyj061/SpikeCV ~/src/SpikeCV
    git clone https://github.com/chenkang455/Spike-Zoo ~/src/Spike-Zoo
    git clone https://github.com/SensorsINI/v2e ~/src/v2e

Run (from the repository root; the recordings default to `../shared/data/real`):

    ~/pyvs/bin/python scripts/python_vs.py --spikecv ~/src/SpikeCV --spikezoo ~/src/Spike-Zoo \\
        --v2e ~/src/v2e --out python_vs.md

Every tool runs on one thread (`ns.set_threads(1)`, `torch.set_num_threads(1)`, and the
`*_NUM_THREADS` variables set before anything is imported), so the ratio compares one core with
one core. A full run takes about a minute on a 2-core machine.
"""

import os

# One thread for every library that reads these (numpy's BLAS, polars under evlib, rayon),
# before any of them is imported. neuspike's own pool is set with ns.set_threads.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS",
             "NUMBA_NUM_THREADS", "POLARS_MAX_THREADS", "RAYON_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import dataclasses  # noqa: E402
import importlib  # noqa: E402
import importlib.metadata  # noqa: E402
import importlib.util  # noqa: E402
import io  # noqa: E402
import logging  # noqa: E402
import pathlib  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from typing import Callable, Optional  # noqa: E402

import numpy as np  # noqa: E402

import neuspike as ns  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real"


class Skip(Exception):
    """A pair that cannot run here; the message says why."""


@dataclasses.dataclass
class Row:
    tool: str
    operation: str
    input: str
    ns_s: float
    ns_more_s: Optional[float]
    other_s: float
    equal: bool
    tolerance: str
    note: str


class Bench:
    """The run's settings, inputs loaded once, and what the pairs report."""

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.reps = args.reps
        self.slow_reps = max(1, (args.reps + 1) // 2)  # for calls of a second or more
        self.rows: list[Row] = []
        self.skipped: list[str] = []
        self._spikes = None
        self._events = None

    @property
    def spikes(self) -> "ns.Spikes":
        if self._spikes is None:
            path = self.args.spikes
            if not path.is_file():
                raise Skip(f"no spike recording at {path} (--spikes)")
            self._spikes = ns.read_spikes(path, width=self.args.spike_width,
                                          height=self.args.spike_height)
        return self._spikes

    @property
    def events(self) -> "ns.Events":
        if self._events is None:
            path = self.args.events
            if not path.is_file():
                raise Skip(f"no event recording at {path} (--events)")
            self._events = ns.read_events(path, width=self.args.event_width,
                                          height=self.args.event_height)
        return self._events

    def time_other(self, fn: Callable, reps: Optional[int] = None):
        """The other tool's median time and the result of its warm-up call."""
        return median_s(fn, reps or self.reps)

    def time_neuspike(self, fn: Callable, reps: Optional[int] = None):
        """neuspike's median time on one thread, on `--threads` (None when 0 or 1), and the
        result of the warm-up call."""
        reps = reps or self.reps
        ns.set_threads(1)
        one, out = median_s(fn, reps)
        more = None
        if self.args.threads > 1:
            ns.set_threads(self.args.threads)
            more, _ = median_s(fn, reps)
            ns.set_threads(1)
        return one, more, out

    def add(self, *args, **kwargs) -> None:
        self.rows.append(Row(*args, **kwargs))

    def skip(self, what: str, why: str) -> None:
        self.skipped.append(f"{what}: {why}")
        print(f"skipped {what}: {why}", file=sys.stderr)


MIN_TIMED_S = 0.25  # fast calls repeat until they fill this much time (up to MAX_CALLS)
MAX_CALLS = 200


def median_s(fn: Callable, reps: int):
    """Median wall time of at least `reps` calls of `fn` (more for fast calls, until they take
    MIN_TIMED_S together) after one warm-up call, and the warm-up's result."""
    out = fn()
    times: list[float] = []
    while len(times) < reps or (sum(times) < MIN_TIMED_S and len(times) < MAX_CALLS):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), out


def need(module: str, install: str):
    """Imports `module` or skips the pair, saying what to install."""
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        raise Skip(f"needs {module} ({install}): {e}") from None
    if module == "torch":
        mod.set_num_threads(1)
    return mod


def checkout(root: Optional[pathlib.Path], option: str, where: str) -> pathlib.Path:
    """The checkout given with `option`, or a skip saying to give one."""
    if root is None:
        raise Skip(f"give {option} DIR, a checkout of {where}")
    if not root.is_dir():
        raise Skip(f"{option} {root}: no such directory")
    return root


def load_file(name: str, root: pathlib.Path, option: str, *candidates: str):
    """Imports one source file of a checkout by path (not its package, whose `__init__` imports
    far more than the file needs)."""
    for rel in candidates:
        path = root / rel
        if path.is_file():
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            return module
    raise Skip(f"{option} {root}: none of {', '.join(candidates)} there")


def mismatches(name: str, ours: np.ndarray, theirs: np.ndarray, unit: str = "") -> list[str]:
    """`name: N differ (up to D unit)`, or nothing when equal."""
    ours, theirs = np.asarray(ours), np.asarray(theirs)
    if ours.shape != theirs.shape:
        return [f"{name}: shapes {ours.shape} and {theirs.shape}"]
    bad = ours != theirs
    if not bad.any():
        return []
    worst = np.abs(ours[bad].astype(np.float64) - theirs[bad].astype(np.float64)).max()
    return [f"{name}: {int(bad.sum()):,} differ (by up to {worst:.6g}{unit})"]


def floor_matches(ours_255: np.ndarray, theirs_u8: np.ndarray, mask=None) -> tuple[bool, float]:
    """Whether the tool's uint8 output is the truncation of 255 x ours, allowing 1e-3 of float
    rounding before the floor; and the largest |255 ours - theirs| seen."""
    if mask is not None:
        ours_255, theirs_u8 = ours_255[mask], theirs_u8[mask]
    theirs = theirs_u8.astype(np.float64)
    ours = ours_255.astype(np.float64)
    ok = bool(np.all((theirs >= np.floor(ours - 1e-3)) & (theirs <= np.floor(ours + 1e-3))))
    return ok, float(np.abs(ours - theirs).max()) if ours.size else 0.0


# ---------------------------------------------------------------------------------------------
# Spike representations: SpikeCV and Spike-Zoo
# ---------------------------------------------------------------------------------------------

def spike_setup(bench: Bench):
    """The recording packed (neuspike's input) and unpacked (the others'), the window around
    `--ref`, and a text for the input column."""
    spikes = bench.spikes
    planes = spikes.unpack()
    half = bench.args.window // 2
    ref = bench.args.ref
    if not half <= ref < len(spikes) - half:
        raise Skip(f"--ref {ref} leaves no {bench.args.window}-plane window in {len(spikes)} planes")
    window = spikes.window(ref - half, ref + half + 1)
    size = f"{spikes.width}x{spikes.height}"
    return spikes, planes, half, ref, window, size


def pairs_spikecv(bench: Bench) -> None:
    """SpikeCV's TFP and TFI (`spkProc/reconstruction/tfp.py`, `tfi.py`), one frame
    (`spikes2frame`) and every frame of the recording (`spikes2images`)."""
    root = checkout(bench.args.spikecv, "--spikecv", "github.com/Zyj061/SpikeCV")
    need("torch", "pip install torch")
    need("cv2", "pip install opencv-python-headless")
    tfp_mod = load_file("spikecv_tfp", root, "--spikecv",
                        "SpikeCV/spkProc/reconstruction/tfp.py", "spkProc/reconstruction/tfp.py")
    tfi_mod = load_file("spikecv_tfi", root, "--spikecv",
                        "SpikeCV/spkProc/reconstruction/tfi.py", "spkProc/reconstruction/tfi.py")
    spikes, planes, half, ref, window, size = spike_setup(bench)
    n, h, w = planes.shape
    width = 2 * half + 1
    floor_tol = "theirs = floor(255 x ours) (1e-3 slack)"

    # One TFP frame: SpikeCV's is the window's mean x 255 truncated to uint8.
    tfp = tfp_mod.TFP(h, w, "cpu")
    other, theirs = bench.time_other(lambda: tfp.spikes2frame(planes, ref, half))
    one, more, ours = bench.time_neuspike(lambda: ns.tfp(window))
    ok, worst = floor_matches(ours * 255, theirs)
    bench.add("SpikeCV", "TFP, one frame", f"{width} of {n} planes, {size}", one, more, other, ok,
              floor_tol, f"SpikeCV gives uint8 255 x mean; max abs(255 ours - theirs) {worst:.3f}; "
              "SpikeCV takes the unpacked planes, neuspike the packed window")

    # Every TFP frame the recording has (a window centred on each plane that has one).
    refs = range(half, n - half)
    windows = [spikes.window(k - half, k + half + 1) for k in refs]
    other, theirs = bench.time_other(lambda: tfp.spikes2images(planes, half), bench.slow_reps)
    one, more, ours = bench.time_neuspike(lambda: [ns.tfp(x) for x in windows])
    ok, worst = floor_matches(np.stack(ours) * 255, theirs)
    bench.add("SpikeCV", f"TFP, {len(refs)} frames", f"{n} planes, {size}, {width}-plane windows",
              one, more, other, ok, floor_tol,
              f"a loop of ns.tfp against spikes2images; max abs(255 ours - theirs) {worst:.3f}")

    # One TFI frame: SpikeCV searches planes ref-half+1..ref back and ref+1..ref+half on, and
    # gives 255 / (2 half) where either side has no spike; compare where both sides have one.
    tfi = tfi_mod.TFI(h, w, "cpu")
    other, theirs = bench.time_other(lambda: tfi.spikes2frame(planes, ref, half))
    one, more, ours = bench.time_neuspike(lambda: ns.tfi(window))
    both = planes[ref - half + 1:ref + 1].any(0) & planes[ref + 1:ref + half + 1].any(0)
    ok, worst = floor_matches(ours * 255, theirs, both)
    bench.add("SpikeCV", "TFI, one frame", f"{width} of {n} planes, {size}", one, more, other, ok,
              floor_tol + ", where both define it",
              f"compared on the {both.mean():.1%} of pixels with a spike in both of SpikeCV's "
              f"search spans (it searches {half} planes back, neuspike {half + 1}); "
              f"max abs(255 ours - theirs) {worst:.3f}")

    # Every TFI frame: spikes2images takes each interval over the whole recording and, on a
    # spike, the interval that ends there (neuspike's starts there). Compare where neuspike's
    # window holds both ends and the reference plane has no spike.
    other, theirs = bench.time_other(lambda: tfi.spikes2images(planes, half), bench.slow_reps)
    one, more, ours = bench.time_neuspike(lambda: [ns.tfi(x) for x in windows])
    valid = np.stack([ns.isi(x)[1] for x in windows])
    both = valid & (planes[half:n - half] == 0)
    ok, worst = floor_matches(np.stack(ours) * 255, theirs, both)
    bench.add("SpikeCV", f"TFI, {len(refs)} frames", f"{n} planes, {size}, {width}-plane windows",
              one, more, other, ok, floor_tol + ", where both define it",
              f"a loop of ns.tfi against spikes2images; compared on the {both.mean():.1%} of "
              "pixel-frames whose interval lies in the window and whose reference plane has no "
              f"spike (SpikeCV then takes the interval ending there); max diff {worst:.3f}")


def pairs_spikezoo(bench: Bench) -> None:
    """Spike-Zoo's reader (`utils/spike_utils.py`, its Python version) and its TFP and TFI
    models (`archs/tfp/nets.py`, `archs/tfi/nets.py`) on one window."""
    root = checkout(bench.args.spikezoo, "--spikezoo", "github.com/chenkang455/Spike-Zoo")
    torch = need("torch", "pip install torch")
    need("cv2", "pip install opencv-python-headless")
    need("imageio", "pip install imageio")
    utils = load_file("spikezoo_spike_utils", root, "--spikezoo", "spikezoo/utils/spike_utils.py")
    tfp_nets = load_file("spikezoo_tfp", root, "--spikezoo", "spikezoo/archs/tfp/nets.py")
    tfi_nets = load_file("spikezoo_tfi", root, "--spikezoo", "spikezoo/archs/tfi/nets.py")
    spikes, planes, half, ref, window, size = spike_setup(bench)
    n, h, w = planes.shape
    width = 2 * half + 1
    path = str(bench.args.spikes)

    # Reading the .dat into unpacked planes (Spike-Zoo's are float32, rows flipped as ours).
    other, theirs = bench.time_other(lambda: utils.load_vidar_dat(path, h, w), bench.slow_reps)
    one, more, ours = bench.time_neuspike(
        lambda: ns.read_spikes(path, width=w, height=h).unpack())
    bad = mismatches("planes", ours, theirs)
    bench.add("Spike-Zoo", "read .dat to planes", f"{n} planes, {size}", one, more, other,
              not bad, "exact", "; ".join(bad) or
              "load_vidar_dat (Python version; its C++ loader is built for CPython 3.9 only) "
              "against ns.read_spikes(...).unpack()")

    # Spike-Zoo's models take a float32 tensor [batch, T, H, W], as its loader makes.
    clip = torch.from_numpy(planes[ref - half:ref + half + 1].astype(np.float32))[None]
    tfp_model = tfp_nets.TFPModel(width)
    with torch.no_grad():
        other, theirs = bench.time_other(lambda: tfp_model(clip))
    one, more, ours = bench.time_neuspike(lambda: ns.tfp(window))
    worst = float(np.abs(theirs[0, 0].numpy() - ours).max())
    bench.add("Spike-Zoo", "TFP, one window", f"{width} planes, {size}", one, more, other,
              worst <= 1e-6, "abs 1e-6",
              f"TFPModel({width}) on a float32 tensor; max abs diff {worst:.2g}")

    # TFI: its backward search stops at the window's plane 1 and it gives 1 / (2 half) where a
    # side has no spike; compare where both sides have one. It hard-codes CUDA: set to the CPU.
    tfi_model = tfi_nets.TFIModel(width)
    tfi_model.device = "cpu"
    with torch.no_grad():
        other, theirs = bench.time_other(lambda: tfi_model(clip))
    one, more, ours = bench.time_neuspike(lambda: ns.tfi(window))
    win = planes[ref - half:ref + half + 1]
    both = win[1:half + 1].any(0) & win[half + 1:].any(0)
    diff = np.abs(theirs[0, 0].numpy() - ours)[both]
    worst = float(diff.max()) if diff.size else 0.0
    bench.add("Spike-Zoo", "TFI, one window", f"{width} planes, {size}", one, more, other,
              worst <= 1e-6, "abs 1e-6, where both define it",
              f"TFIModel({width}) on the CPU; compared on the {both.mean():.1%} of pixels with a "
              f"spike in planes 1..{half} and {half + 1}..{2 * half} of the window (elsewhere "
              f"Spike-Zoo gives 1/{2 * half}); max abs diff {worst:.2g}")


# ---------------------------------------------------------------------------------------------
# Event representations: tonic
# ---------------------------------------------------------------------------------------------

def pairs_tonic(bench: Bench) -> None:
    """tonic's voxel grid and frames by time bins against neuspike's voxel grid and event
    stack, on inputs converted so that both compute the same thing."""
    F = need("tonic.functional", "pip install tonic")
    events = bench.events
    bins = bench.args.bins
    width, height = events.width, events.height
    count = len(events)
    label = f"{count:,} events, {width}x{height}, {bins} bins"
    t_ns = events.t_ns
    span = int(t_ns[-1] - t_ns[0])

    # Voxel grid. tonic scales times by B over [t0, t_last] (neuspike by B - 1) and drops what
    # falls in bin B, and maps polarity 0 to -1 in place (with a bool column OFF then counts
    # +1). So: polarity as int +1/-1, and one extra event at t0 + span B / (B - 1), which makes
    # tonic's scale B - 1 and itself lands in the dropped bin.
    grid_in = np.zeros(count + 1, dtype=[("x", "<i2"), ("y", "<i2"), ("t", "<f8"), ("p", "<i2")])
    grid_in["x"][:count], grid_in["y"][:count] = events.x, events.y
    grid_in["p"][:count] = events.polarity
    grid_in["t"][:count] = (t_ns - t_ns[0]).astype(np.float64)
    grid_in["t"][count], grid_in["p"][count] = span * bins / (bins - 1), 1
    sensor = (width, height, 2)
    other, theirs = bench.time_other(lambda: F.to_voxel_grid_numpy(grid_in, sensor, bins))
    one, more, ours = bench.time_neuspike(lambda: ns.voxel_grid(events, bins))
    worst = float(np.abs(theirs[:, 0] - ours).max())
    plain = np.zeros(count, dtype=[("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i2")])
    plain["x"], plain["y"], plain["t"], plain["p"] = events.x, events.y, t_ns // 1000, events.polarity
    unconverted = float(np.abs(F.to_voxel_grid_numpy(plain, sensor, bins)[:, 0] - ours).max())
    bench.add("tonic", "voxel grid", label, one, more, other, worst <= 1e-4, "abs 1e-4",
              f"to_voxel_grid_numpy with int polarity and a phantom last event for the B - 1 "
              f"scale; max abs diff {worst:.2g} (unconverted, µs times: {unconverted:.3g}, of "
              f"values up to {np.abs(ours).max():.3g})")

    # Event stack. tonic's frames by time bins are windows floor(span / B) long, half-open, so
    # the last instant falls outside, with ON and OFF counted apart. So: times x B (the windows
    # become exactly `span` long), events at the last instant 1 earlier (still in bin B - 1),
    # one extra event at span x B (outside every window), and ON - OFF.
    stack_in = np.zeros(count + 1, dtype=[("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i2")])
    stack_in["x"][:count], stack_in["y"][:count] = events.x, events.y
    stack_in["p"][:count] = events.polarity > 0
    scaled = (t_ns - t_ns[0]) * bins
    scaled[t_ns == t_ns[-1]] -= 1
    stack_in["t"][:count] = scaled
    stack_in["t"][count], stack_in["p"][count] = span * bins, 1
    other, theirs = bench.time_other(lambda: F.to_frame_numpy(stack_in, sensor, n_time_bins=bins))
    one, more, ours = bench.time_neuspike(lambda: ns.event_stack(events, bins))
    signed = theirs[:, 1].astype(np.int32) - theirs[:, 0]
    bad = mismatches("counts", ours, signed)
    bench.add("tonic", "event stack", label, one, more, other, not bad, "exact",
              "; ".join(bad) or "to_frame_numpy(n_time_bins) ON - OFF, times x B, the last "
              "instant 1 earlier and a phantom event closing the last window")


# ---------------------------------------------------------------------------------------------
# Event readers: expelliarmus, evlib, aestream, dv-processing
# ---------------------------------------------------------------------------------------------

def read_expelliarmus(path: pathlib.Path, fmt: str, size):
    from expelliarmus import Wizard
    a = Wizard(encoding=fmt, fpath=str(path)).read()
    return a["t"], a["x"], a["y"], a["p"] > 0


def read_evlib(path: pathlib.Path, fmt: str, size):
    import evlib
    import polars as pl
    df = evlib.load_events(str(path), sort=False).collect()  # file order, as the others
    return (df["t"].cast(pl.Int64).to_numpy(), df["x"].to_numpy(), df["y"].to_numpy(),
            df["polarity"].to_numpy() > 0)


def read_aestream(path: pathlib.Path, fmt: str, size):
    import aestream
    a = aestream.FileInput(str(path), size).load()
    return a["timestamp"], a["x"], a["y"], a["polarity"] > 0


def read_dv(path: pathlib.Path, fmt: str, size):
    import dv_processing as dv
    recording = dv.io.MonoCameraRecording(str(path))
    parts = []
    while (batch := recording.getNextEventBatch()) is not None:
        parts.append(batch.numpy())
    a = np.concatenate(parts)
    return a["timestamp"], a["x"], a["y"], a["polarity"] > 0


# tool: (module, pip name, reader, the formats to try). A format a tool cannot read is skipped
# with its error; HINTS add what is known about why.
READERS = {
    "expelliarmus": ("expelliarmus", "expelliarmus", read_expelliarmus, ("evt2", "evt3", "dat")),
    "evlib": ("evlib", "evlib", read_evlib, ("evt2", "evt3", "dat", "aedat4")),
    "aestream": ("aestream", "aestream", read_aestream, ("evt2", "evt3", "dat", "aedat4")),
    "dv-processing": ("dv_processing", "dv-processing", read_dv, ("aedat4",)),
}
HINTS = {
    ("evlib", "dat"): "evlib takes a .dat by its extension for a text file",
    ("aestream", "evt2"): "aestream decodes every .raw file as EVT 3.0",
    ("aestream", "aedat4"): "aestream needs the optional file data table "
                            "(neuspike writes dataTablePosition -1, as the format allows)",
}
FORMAT_NAMES = {"evt2": "Prophesee RAW EVT 2.0", "evt3": "Prophesee RAW EVT 3.0",
                "dat": "Prophesee DAT", "aedat4": "AEDAT 4"}


def pairs_readers(bench: Bench, tmp: pathlib.Path) -> None:
    """Each reader on each format it claims, against ns.read_events of the same file: the count
    and every column (times in µs x 1000, polarity as ON or not)."""
    events = bench.events
    files = {"evt2": bench.args.events}
    for fmt, name in (("evt3", "events.raw"), ("dat", "events.dat"), ("aedat4", "events.aedat4")):
        files[fmt] = tmp / name
        ns.write_events(files[fmt], events)
    size = (events.width, events.height)
    for tool, (module, pip_name, reader, formats) in READERS.items():
        try:
            need(module, f"pip install {pip_name}")
        except Skip as e:
            bench.skip(f"{tool} readers", str(e))
            continue
        for fmt in formats:
            path = files[fmt]
            what = f"{tool} reading {FORMAT_NAMES[fmt]}"
            try:
                other, (t_us, x, y, on) = bench.time_other(lambda: reader(path, fmt, size))
            except Exception as e:  # the tool's own error, whatever its class
                hint = HINTS.get((tool, fmt))
                bench.skip(what, f"{type(e).__name__}: {e}" + (f" ({hint})" if hint else ""))
                continue
            one, more, ours = bench.time_neuspike(
                lambda: ns.read_events(path, width=size[0], height=size[1]))
            bad = ([] if len(t_us) == len(ours) else [f"count {len(t_us):,} vs {len(ours):,}"])
            if not bad:
                bad = (mismatches("t", ours.t_ns // 1000, np.asarray(t_us, np.int64), " µs")
                       + mismatches("x", ours.x, x) + mismatches("y", ours.y, y)
                       + mismatches("polarity", ours.polarity > 0, on))
            origin = "the recording" if fmt == "evt2" else "written by ns.write_events"
            notes = ["load_events(sort=False), file order"] if tool == "evlib" else []
            notes += bad
            if bad and (tool, fmt) in MISMATCH_NOTES:
                notes.append(MISMATCH_NOTES[(tool, fmt)])
            bench.add(tool, f"read {FORMAT_NAMES[fmt]}", f"{len(ours):,} events, {origin}",
                      one, more, other, not bad, "exact (count and every column)", "; ".join(notes))


# What is known of the EVT 3.0 differences (expelliarmus 1.1.12, evlib 0.13.2, aestream 0.6.4).
# neuspike's writer leaves out a TIME_LOW of 0 right after a TIME_HIGH (its reader takes a
# TIME_HIGH as clearing the low bits); the Prophesee format says only that TIME_HIGH sets the
# upper 12 bits, and these readers keep the last TIME_LOW.
MISMATCH_NOTES = {
    ("evlib", "evt3"): "the events after a TIME_HIGH with no TIME_LOW 0 after it read up to "
                       "4,095 µs late: neuspike's writer leaves that TIME_LOW out",
    ("expelliarmus", "evt3"): "expelliarmus adds 4,096 µs at every TIME_LOW wrap on top of the "
                              "TIME_HIGH, so its times drift from the first wrap, with or "
                              "without a TIME_LOW 0 after the TIME_HIGH",
    ("aestream", "evt3"): "aestream's times are 4,096 µs late from the first event and not "
                          "monotonic: its own EVT 3.0 decoding",
}


# ---------------------------------------------------------------------------------------------
# DVS simulation: v2e
# ---------------------------------------------------------------------------------------------

def panned_frames(n: int, height: int, width: int, px_per_frame: float) -> np.ndarray:
    """`n` frames of a smooth texture moving right, luminance in [0.1, 1] (v2e takes plain logs
    above 20 of 255)."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    frames = np.empty((n, height, width), np.float32)
    for k in range(n):
        sx = xx - px_per_frame * k
        frames[k] = 0.55 + 0.45 * (0.6 * np.sin(2 * np.pi * sx / 37) * np.cos(2 * np.pi * yy / 23)
                                   + 0.4 * np.sin(2 * np.pi * (sx + yy) / 61))
    return frames


def pairs_v2e(bench: Bench) -> None:
    """ns.simulate's DVS against v2e's EventEmulator on the same frames, both without noise."""
    root = checkout(bench.args.v2e, "--v2e", "github.com/SensorsINI/v2e")
    need("torch", "pip install torch")
    sys.path.insert(0, str(root))
    try:
        emulator = need("v2ecore.emulator", "pip install torch opencv-python-headless h5py "
                        "screeninfo engineering-notation easygui dv-processing")
    finally:
        sys.path.pop(0)
    n, height, width, dt_ns = bench.args.v2e_frames + 1, 260, 346, 1_000_000
    frames = panned_frames(n, height, width, 0.1)
    theta = 0.2

    def v2e_run():
        quiet = logging.root.manager.disable
        logging.disable(logging.WARNING)
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                emu = emulator.EventEmulator(
                    pos_thres=theta, neg_thres=theta, sigma_thres=0.0, cutoff_hz=0.0,
                    leak_rate_hz=0.0, shot_noise_rate_hz=0.0, refractory_period_s=0.0,
                    device="cpu", output_width=width, output_height=height)
                counts = np.zeros((height, width), np.int64)
                on = off = 0
                for k in range(n):
                    ev = emu.generate_events(frames[k].astype(np.float64) * 255.0, k * dt_ns * 1e-9)
                    if ev is None or len(ev) == 0:
                        continue
                    p = ev[:, 3].astype(np.int64)
                    np.add.at(counts, (ev[:, 2].astype(np.int64), ev[:, 1].astype(np.int64)), p)
                    on += int((p > 0).sum())
                    off += int((p < 0).sum())
        finally:
            logging.disable(quiet)
        return on, off, counts

    camera = {"theta_on": theta, "theta_off": theta, "theta_sigma": 0.0}

    def ns_run():
        return ns.frames_to_events(frames, dt_ns, event_camera=camera)

    def ns_scene():
        # The same frames as a scene (light linear between frames), the DVS alone.
        planes = (n - 1) * dt_ns // 50_000
        return ns.simulate(frames=frames, frame_dt_ns=dt_ns, planes=planes, truth_every=0,
                           spikes=False, event_camera=camera).events

    other, (on, off, v2e_counts) = bench.time_other(v2e_run, bench.slow_reps)
    one, more, ev = bench.time_neuspike(ns_run, bench.slow_reps)
    scene_s, _, scene_ev = bench.time_neuspike(ns_scene, bench.slow_reps)
    pol = np.asarray(ev.polarity)
    ns_on, ns_off = int((pol > 0).sum()), int((pol < 0).sum())
    ours = np.zeros((height, width), np.int64)
    np.add.at(ours, (np.asarray(ev.y, np.int64), np.asarray(ev.x, np.int64)), pol.astype(np.int64))
    corr = float(np.corrcoef(ours.ravel(), v2e_counts.ravel())[0, 1])
    factor = bench.args.v2e_factor
    ratios = [ns_on / max(on, 1), ns_off / max(off, 1)]
    ok = all(1 / factor <= r <= factor for r in ratios)
    bench.add("v2e", "DVS events from frames", f"{n - 1} frames of 1 ms, {width}x{height}",
              one, more, other, ok, f"ON and OFF counts within x{factor:g}",
              f"ns.frames_to_events against EventEmulator.generate_events, ideal DVS both "
              f"(theta 0.2, no mismatch, leak, shot noise, low-pass, refractory); ON/OFF v2e "
              f"{on:,}/{off:,}, neuspike {ns_on:,}/{ns_off:,}; per-pixel signed count "
              f"correlation {corr:.3f}. Both step frame to frame in log intensity; neuspike "
              f"times each crossing inside the interval. The frames as a scene "
              f"(ns.simulate(frames=..., spikes=False), {len(scene_ev):,} events) take "
              f"{scene_s * 1e3:.0f} ms: the scene path renders the light between frames at "
              f"the DVS's step; v2e's time includes making its emulator")


# ---------------------------------------------------------------------------------------------
# Output
# ---------------------------------------------------------------------------------------------

def fmt_s(s: Optional[float]) -> str:
    if s is None:
        return "-"
    return f"{s:.3g} s" if s >= 1 else f"{s * 1e3:.3g} ms"


def version(dist: str) -> Optional[str]:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def report(bench: Bench) -> str:
    args = bench.args
    tools = ", ".join(f"{d} {v}" for d in ("neuspike", "numpy", "torch", "tonic", "expelliarmus",
                                            "evlib", "aestream", "dv-processing")
                      if (v := version(d)))
    checkouts = ", ".join(f"{name} {path}" for name, path in
                          (("SpikeCV", args.spikecv), ("Spike-Zoo", args.spikezoo), ("v2e", args.v2e))
                          if path)
    extra = args.threads > 1
    more = f" neuspike {args.threads} threads |" if extra else ""
    lines = [
        f"Python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} cores; "
        f"{tools}" + (f"; {checkouts}" if checkouts else ""),
        f"Median of at least {bench.reps} calls ({bench.slow_reps} for the slow ones; fast "
        f"ones repeat to fill {MIN_TIMED_S:g} s) after a warm-up; one thread each; "
        "ratio = other / neuspike (one thread).",
        "",
        f"| tool | operation | input | neuspike 1 thread |{more} tool, 1 thread | ratio "
        "| equal | tolerance | note |",
        "|---" * (10 if extra else 9) + "|",
    ]
    for r in bench.rows:
        ratio = r.other_s / r.ns_s
        more = f" {fmt_s(r.ns_more_s)} |" if extra else ""
        lines.append(
            f"| {r.tool} | {r.operation} | {r.input} | {fmt_s(r.ns_s)} |{more} "
            f"{fmt_s(r.other_s)} | {ratio:.3g}x | {'yes' if r.equal else '**no**'} "
            f"| {r.tolerance} | {r.note} |")
    if bench.skipped:
        lines += ["", "Skipped:", ""] + [f"- {s}" for s in bench.skipped]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spikecv", type=pathlib.Path, help="a checkout of github.com/Zyj061/SpikeCV")
    ap.add_argument("--spikezoo", type=pathlib.Path,
                    help="a checkout of github.com/chenkang455/Spike-Zoo")
    ap.add_argument("--v2e", type=pathlib.Path, help="a checkout of github.com/SensorsINI/v2e")
    ap.add_argument("--spikes", type=pathlib.Path, default=REAL / "vidar-car-400x250.dat",
                    help="a PKU spike .dat recording (default: the real Vidar one)")
    ap.add_argument("--spike-width", type=int, default=400)
    ap.add_argument("--spike-height", type=int, default=250)
    ap.add_argument("--window", type=int, default=33, help="planes per TFP / TFI window (odd)")
    ap.add_argument("--ref", type=int, default=100, help="the one-frame pairs' reference plane")
    ap.add_argument("--events", type=pathlib.Path, default=REAL / "prophesee-evt2-640x480.raw",
                    help="a Prophesee EVT 2.0 RAW recording (default: the real one)")
    ap.add_argument("--event-width", type=int, default=640)
    ap.add_argument("--event-height", type=int, default=480)
    ap.add_argument("--bins", type=int, default=5, help="voxel grid and event stack bins")
    ap.add_argument("--v2e-frames", type=int, default=100, help="1 ms frames for the v2e pair")
    ap.add_argument("--v2e-factor", type=float, default=1.05,
                    help="how far the DVS event counts may differ, as a factor")
    ap.add_argument("--reps", type=int, default=5, help="timed calls per side (median)")
    ap.add_argument("--threads", type=int, default=2,
                    help="neuspike's extra column's thread count (0 or 1: no such column)")
    ap.add_argument("--out", type=pathlib.Path, help="also write the Markdown here")
    args = ap.parse_args()
    if args.window < 3 or args.window % 2 == 0:
        ap.error("--window must be odd and at least 3")
    if args.bins < 2:
        ap.error("--bins must be at least 2")

    ns.set_threads(1)
    bench = Bench(args)
    with tempfile.TemporaryDirectory() as tmp:
        pairs = [("SpikeCV", pairs_spikecv), ("Spike-Zoo", pairs_spikezoo), ("tonic", pairs_tonic),
                 ("event readers", lambda b: pairs_readers(b, pathlib.Path(tmp))),
                 ("v2e", pairs_v2e)]
        for name, run in pairs:
            print(f"running {name} ...", file=sys.stderr)
            try:
                run(bench)
            except Skip as e:
                bench.skip(name, str(e))
            except Exception as e:  # a tool failing midway: say so and go on with the others
                bench.skip(name, f"failed: {type(e).__name__}: {e}")
    text = report(bench)
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
