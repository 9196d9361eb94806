"""Writes the AEDAT 4 fixtures with iniVation's own writer (dv-processing 2.0.4) and the facts the
reader tests check (`*.facts`), computed by dv-processing's reader.

    python -m venv /tmp/dv && /tmp/dv/bin/pip install dv-processing==2.0.4 numpy
    /tmp/dv/bin/python formats/tests/data/make_aedat4_fixtures.py formats/tests/data

Events are random (seeded), frames are smooth gradients (so the files stay small).
"""

import json
import sys

import dv_processing as dv
import numpy as np

out = sys.argv[1]
W, H = 346, 260
T0 = 1_600_000_000_000_000  # µs, as DV's Unix-epoch clock
for name, comp in [("lz4", dv.CompressionType.LZ4), ("zstd", dv.CompressionType.ZSTD)]:
    rng = np.random.default_rng(7)
    cfg = dv.io.MonoCameraWriter.DAVISConfig("DAVIS346_fixture", (W, H))
    cfg.compression = comp
    path = f"{out}/dv-{name}.aedat4"
    w = dv.io.MonoCameraWriter(path, cfg)
    for p in range(3):
        store = dv.EventStore()
        ts = np.sort(rng.integers(0, 10_000, 1000)) + T0 + p * 10_000
        for t in ts:
            store.push_back(int(t), int(rng.integers(0, W)), int(rng.integers(0, H)), bool(rng.integers(0, 2)))
        w.writeEvents(store)
        yy, xx = np.mgrid[0:H, 0:W]
        img = ((xx + 2 * yy + 40 * p) % 256).astype(np.uint8)
        w.writeFrame(dv.Frame(int(T0 + p * 10_000 + 5_000), img))
    del w

    r = dv.io.MonoCameraRecording(path)
    t, x, y, on = [], [], [], []
    frames = []
    while r.isRunning():
        ev = r.getNextEventBatch()
        if ev is not None and ev.size() > 0:
            a = ev.numpy()
            t += a["timestamp"].tolist()
            x += a["x"].tolist()
            y += a["y"].tolist()
            on += a["polarity"].astype(int).tolist()
    r = dv.io.MonoCameraRecording(path)
    while r.isRunning():
        f = r.getNextFrame()
        if f is not None:
            frames.append({"t_us": f.timestamp, "sum": int(f.image.astype(np.int64).sum()),
                           "width": f.image.shape[1], "height": f.image.shape[0]})
    # One fact per line, `key values...`, read by formats/tests/aedat4.rs.
    lines = [
        f"size {W} {H}", f"events {len(t)}", f"on {int(sum(on))}",
        f"first {t[0]} {x[0]} {y[0]} {on[0]}", f"last {t[-1]} {x[-1]} {y[-1]} {on[-1]}",
        f"sums {int(sum(v - T0 for v in t))} {int(sum(x))} {int(sum(y))}",
    ] + [f"frame {f['t_us']} {f['sum']} {f['width']} {f['height']}" for f in frames]
    with open(f"{out}/dv-{name}.facts", "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print(name, len(t), len(frames))
