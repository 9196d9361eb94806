"""Seeds for the fuzz targets, from real recordings and from messages made by programs other than
neuspike's Rust code (its Python package, rosbags): `python3 seeds.py` fills `corpus/<target>/`.

Each format target reads its options from the input's first byte (src/lib.rs), so its seeds get
one; the network targets (`ipc`, `ros2_cdr`) take the bytes as they arrive.
"""

import shutil
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DATA = ROOT.parent / "shared" / "data" / "real"
sys.path.insert(0, str(ROOT / "python"))


def put(target: str, name: str, data: bytes, option: int | None = None) -> None:
    d = HERE / "corpus" / target
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_bytes((bytes([option]) if option is not None else b"") + data)


def recordings() -> None:
    for f in sorted(DATA.glob("*")):
        head = f.read_bytes()[: 256 * 1024]
        put("sniff", f.name, head)
        if f.suffix == ".raw":
            put("raw", f.name, head, 0x01)
        if f.suffix == ".txt":
            put("text", f.name, head[:64 * 1024], 0x02)
        if f.suffix == ".dat" and "vidar" in f.name:
            put("pku", f.name, head[: 3 * 12500], 0x00)
    for f in sorted((ROOT / "formats" / "tests" / "data").glob("*")):
        data = f.read_bytes()[: 600 * 1024]
        put("sniff", f.name, data[:4096])
        if f.suffix == ".aedat4":
            put("aedat4", f.name, data, 0x21)
        if f.suffix == ".dat":
            put("prophesee_dat", f.name, data, 0x01)


def npy() -> None:
    """NumPy headers of versions 1 and 2, C and Fortran order, as numpy writes them."""
    import io

    import numpy as np

    a = np.zeros((2, 3, 4), np.float32)
    for name, arr, version in [("c-v1.npy", a, (1, 0)), ("f-v1.npy", np.asfortranarray(a), (1, 0)),
                               ("c-v2.npy", a, (2, 0))]:
        buf = io.BytesIO()
        np.lib.format.write_array(buf, arr, version=version)
        put("npy", name, buf.getvalue())


def prophesee_dat() -> None:
    """A small CD events file as Prophesee's tools write it: `%` header lines, the event type and
    size bytes, then 8-byte events (µs time; x in bits 0-13, y 14-27, polarity 28-31)."""
    head = b"% Date 2026-01-01 00:00:00\n% Version 2\n% Width 40\n% Height 30\n"
    ev = [(t, (t % 40) | ((t % 30) << 14) | ((t & 1) << 28)) for t in range(0, 400, 7)]
    body = b"".join(np.array([t, w], "<u4").tobytes() for t, w in ev)
    put("prophesee_dat", "cd", head + bytes([0x0C, 8]) + body, 0x01)


def messages() -> None:
    import neuspike
    from neuspike import Credit, EventBatch, Frame, Representation, SpikeChunk

    rng = np.random.default_rng(0)
    msgs = {
        "frame": Frame("reconstruction", "tfp", 5, 7, 3, rng.random((5, 7), np.float32)),
        "representation": Representation("tfp", 1, 2, rng.random((2, 3, 4), np.float32), {"window": 33.0}),
        "spike_chunk": SpikeChunk.from_planes(
            (rng.random((2, 3, 9)) < 0.5).astype(np.uint8),
            first_plane=0, t_first_ns=0, plane_period_ns=50_000, seq=0, lum_per_rate=2.0,
        ),
        "event_batch": EventBatch(
            40, 30, 0, 100, 1, np.array([1, 5, 9]), np.array([1, 2, 3], np.uint16),
            np.array([4, 5, 6], np.uint16), np.array([1, -1, 1], np.int8),
        ),
        "credit": Credit(True, [("align/windows", 8)]),
    }
    for name, m in msgs.items():
        meta, data = m.to_arrow()
        put("ipc", name, neuspike.encode(type(m).TYPE_URN, meta, data))
    meta, data = neuspike.end_of_stream(Frame, 4, cut=True)
    put("ipc", "end_of_stream", neuspike.encode(Frame.TYPE_URN, meta, data))


def ros2() -> None:
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(
        "std_msgs/Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\n"
        "string encoding\nbool is_bigendian\nuint8[] events\n",
        "event_camera_msgs/msg/EventPacket",
    ))
    T = store.types
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=2), frame_id="cam")
    img = T["sensor_msgs/msg/Image"](
        header=header, height=2, width=3, encoding="mono8", is_bigendian=0, step=3,
        data=np.arange(6, dtype=np.uint8),
    )
    put("ros2_cdr", "image", bytes(store.serialize_cdr(img, "sensor_msgs/msg/Image")))
    # EVT 3.0: time high, time low, row, two columns (one ON); `mono`: two 8-byte events.
    evt3 = np.array([0x8001, 0x6002, 0x0003, 0x2804, 0x2005], "<u2").tobytes()
    mono = np.array([(1 << 63) | (3 << 48) | (4 << 32) | 10, (5 << 48) | (6 << 32) | 20], "<u8").tobytes()
    for name, enc, events in (("evt3", "evt3", evt3), ("mono", "mono", mono)):
        p = T["event_camera_msgs/msg/EventPacket"](
            header=header, height=30, width=40, seq=7, time_base=1000, encoding=enc,
            is_bigendian=False, events=np.frombuffer(events, np.uint8),
        )
        put("ros2_cdr", name, bytes(store.serialize_cdr(p, "event_camera_msgs/msg/EventPacket")))


def yaml() -> None:
    """The graphs and the policy shipped, and graphs of the shapes `neuspike run` derives: one
    process for several stages, a foreign node with declared types, credits written out."""
    for f in sorted((ROOT / "graphs").glob("*.yml")) + sorted((ROOT / "examples").glob("*/graph.yml")):
        put("graph", f"{f.parent.name}-{f.name}", f.read_bytes())
    put("graph", "processes.yml", b"""nodes:
  - id: camera
    path: neuspike-spike-source
    args: --scene bright-slow
  - id: align
    path: neuspike-align
    inputs: {spikes: camera/spikes}
  - id: represent
    path: neuspike-represent
    inputs: {windows: align/windows}
  - id: viewer
    path: python3
    args: view.py
    inputs: {frames: {source: represent/tfp, queue_size: 2}}
    input_types: {frames: neuspike/messages/v1/Frame}
processes:
  core: [camera, align, represent]
""")
    put("policy", "policy.yml", (ROOT / "models" / "policy.yml").read_bytes())
    put("policy", "small.yml", b"""version: 2
provenance: {command: fuzz, data: none, date: '2026-12-05'}
db_per_ms: 0.5
scale: [0.3, 0.3, 1.0, 0.3, 0.3]
neighbours: 3
classes:
  - class: dark
    method: tfp-33
    psnr_db: 20.0
    best_psnr_db: 24.0
    ranked:
      - {method: tfp-33, psnr_db: 20.0, ms: 1.0}
      - {method: neuspike-spike-8, psnr_db: 24.0, ms: 10.0}
rows:
  - {class: dark, rate: 0.01, event_rate: 0.0, change: 0.1, spread_decades: 1.0, edge: 0.1}
""")


if __name__ == "__main__":
    shutil.rmtree(HERE / "corpus", ignore_errors=True)
    recordings()
    prophesee_dat()
    npy()
    messages()
    ros2()
    yaml()
    for d in sorted((HERE / "corpus").iterdir()):
        print(d.name, len(list(d.iterdir())))
