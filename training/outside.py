"""Scores networks on spikes that another simulator made: the check that a network carries over
beyond the data of neuspike's own simulator.

Two steps, with any spike-camera simulator between them (none ships here: the point is data the
project was not tuned to):

    # 1. Clips: held-out photos panned across the frame, one frame per 20 kHz tick.
    python training/outside.py frames --photos data/textures/test --out outside/frames
    # 2. Any simulator turns each outside/frames/<clip>.npy ([T, H, W] float32 intensity, one
    #    frame a tick) into outside/<sim>/<clip>.npy ([T, H, W] uint8 spikes).
    # 3. The windows as a `neuspike dataset` folder, then scored like the held-out set:
    python training/outside.py windows --frames outside/frames --spikes outside/<sim> \
        --lum-per-rate 1 --out outside/<sim>-set
    python training/evaluate.py --test outside/<sim>-set models/neuspike-spike-8.onnx
    # With an event-camera simulator's events from the same frames (outside/<dvs>/<clip>.npz:
    # t_ns, x, y, p, one frame a tick from t = 0), the set gains the fused networks' input:
    python training/outside.py windows ... --events outside/<dvs> --out outside/<sim>-<dvs>-set

A window is 33 ticks around a reference tick; its spike representation is the represent node's
(`stages/representations/src/spike.rs`): channel 0 is `1 / ISI` at the reference (the last spike at or
before it to the first after; a side with no spike taken as the nearest tick outside the
window), channels 1-31 the raw planes around it. TFP (the window's rate) and TFI are the classical
baselines, calibrated like the network by `lum_per_rate`: the simulator's luminance per spike a
tick, times the clip's light scale's inverse. The ground truth is the frame at the reference tick.
"""

import argparse
import csv
import json
import pathlib

import numpy as np

WINDOW = 33
CHANNELS = 32
RATE_HZ = 20_000.0


def isi_channel(planes: np.ndarray, c: int) -> np.ndarray:
    """`1 / ISI` at plane `c` of `planes` ([N, H, W] 0/1), as the represent node computes it."""
    n = planes.shape[0]
    fired = planes.astype(bool)
    before = fired[: c + 1][::-1]  # c, c-1, ..., 0
    after = fired[c + 1 :]  # c+1, ..., n-1
    has_prev, has_next = before.any(0), after.any(0)
    prev = np.where(has_prev, c - before.argmax(0), -1)
    nxt = np.where(has_next, c + 1 + after.argmax(0), n)
    return (1.0 / (nxt - prev)).astype(np.float32)


def represent(planes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The spike representation ([32, H, W]), TFP's rate and TFI's rate of one window."""
    n = planes.shape[0]
    c = n // 2
    raw = CHANNELS - 1
    start = min(max(c - raw // 2, 0), n - raw)
    isi = isi_channel(planes, c)
    rep = np.concatenate([isi[None], planes[start : start + raw].astype(np.float32)])
    return rep, planes.mean(0, dtype=np.float64).astype(np.float32), isi


def shifted(photo: np.ndarray, x0: float, y0: float, size: int) -> np.ndarray:
    """The `size` x `size` view of `photo` whose corner is at `(x0, y0)`, bilinear."""
    from scipy.ndimage import map_coordinates

    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    return map_coordinates(photo, [yy + y0, xx + x0], order=1, mode="reflect").astype(np.float32)


def frames_cmd(args: argparse.Namespace) -> None:
    from skimage.io import imread

    rng = np.random.default_rng(args.seed)
    photos = sorted(args.photos.glob("*.png"))
    if not photos:
        raise SystemExit(f"--photos {args.photos}: no PNG files there")
    args.out.mkdir(parents=True, exist_ok=False)
    clips = []
    for k in range(args.clips):
        path = photos[rng.integers(len(photos))]
        photo = imread(path).astype(np.float64)
        photo = photo.mean(2) if photo.ndim == 3 else photo
        photo = photo / max(photo.max(), 1e-9)
        speed = float(args.speeds[k % len(args.speeds)])
        light = float(args.lights[(k // len(args.speeds)) % len(args.lights)])
        angle = rng.uniform(0, 2 * np.pi)
        vx, vy = speed * np.cos(angle) / RATE_HZ, speed * np.sin(angle) / RATE_HZ
        # The view stays inside the photo from tick `inside_from` on (the scored windows); the
        # warm-up before it may reach past the edge, where the photo is mirrored.
        h, w = photo.shape
        span = args.ticks - args.inside_from

        def start(v: float, side: int) -> float:
            lo, hi = max(0.0, -v * span), min(side - args.size, side - args.size - v * span)
            if hi < lo:
                raise SystemExit(f"{path}: {side} pixels cannot hold a {args.size}-pixel view "
                                 f"moving {abs(v) * span:.0f} pixels")
            return rng.uniform(lo, hi) - v * args.inside_from

        x0, y0 = start(vx, w), start(vy, h)
        frames = np.stack(
            [light * shifted(photo, x0 + vx * t, y0 + vy * t, args.size) for t in range(args.ticks)]
        )
        name = f"clip{k:03d}"
        np.save(args.out / f"{name}.npy", frames.astype(np.float32))
        clips.append({"clip": name, "photo": path.name, "speed_px_s": speed, "light": light,
                      "angle_deg": round(float(np.degrees(angle)), 2)})
    (args.out / "clips.json").write_text(json.dumps(clips, indent=1))
    print(f"{args.out}: {len(clips)} clips of {args.ticks} ticks, {args.size}x{args.size}")


def event_windows(
    spikes: np.ndarray, path: pathlib.Path, refs: list[int], every: int, reps: list[np.ndarray]
) -> list[np.ndarray]:
    """The event integration of each window around `refs`, made by the neuspike package's align
    and represent stages from `spikes` ([T, H, W]) and the events in `path`, exactly as `neuspike
    dataset` makes a sample's. Align cuts windows at plane numbers that are multiples of its
    stride, so the clip is renumbered to put the first reference at one; the spike
    representation it makes alongside must equal `reps` (this module's), or the windows differ.
    `refs` are `every` ticks apart."""
    import neuspike

    ev = np.load(path)
    t, h, w = spikes.shape
    if (int(ev["height"]), int(ev["width"])) != (h, w):
        raise SystemExit(f"{path}: events of {int(ev['width'])}x{int(ev['height'])}, spikes of {w}x{h}")
    shift = refs[0] % every
    tick_ns = round(1e9 / RATE_HZ)
    keep = ev["t_ns"] >= shift * tick_ns
    events = neuspike.Events(
        ev["t_ns"][keep] - shift * tick_ns, ev["x"][keep], ev["y"][keep], ev["p"][keep], w, h,
        t_start_ns=0, t_end_ns=(t - shift) * tick_ns,
    )
    made = neuspike.represent(
        neuspike.Spikes.from_planes(spikes[shift:], plane_period_ns=tick_ns), events,
        kinds=["spike_repr", "event_integration"], window_planes=WINDOW, stride_planes=every,
    )
    at = {int(r) // tick_ns + shift: i for i, r in enumerate(made["t_ref_ns"])}
    out = []
    for c, rep in zip(refs, reps):
        if c not in at:
            raise SystemExit(f"{path}: align made no window around tick {c}")
        if not np.array_equal(made["spike_repr"][at[c]], rep):
            raise SystemExit(f"{path}: the window around tick {c} is not the one cut here")
        out.append(made["event_integration"][at[c]])
    return out


def windows_cmd(args: argparse.Namespace) -> None:
    clips = json.loads((args.frames / "clips.json").read_text())
    reps, truths, tfps, tfis, rows, events = [], [], [], [], [], []
    for clip in clips:
        frames = np.load(args.frames / f"{clip['clip']}.npy")
        spikes = np.load(args.spikes / f"{clip['clip']}.npy")
        if spikes.shape != frames.shape:
            raise SystemExit(f"{args.spikes}/{clip['clip']}.npy: shape {spikes.shape}, frames {frames.shape}")
        if spikes.max() > 1:
            raise SystemExit(f"{args.spikes}/{clip['clip']}.npy: values up to {spikes.max()}, spikes are 0/1")
        lum_per_rate = args.lum_per_rate / clip["light"]
        for c in range(args.warmup + WINDOW // 2, spikes.shape[0] - WINDOW // 2, args.every):
            planes = spikes[c - WINDOW // 2 : c + WINDOW // 2 + 1]
            rep, rate, isi = represent(planes)
            reps.append(rep)
            truths.append(np.clip(frames[c] / clip["light"], 0, 1))
            tfps.append(np.clip(rate * lum_per_rate, 0, 1))
            tfis.append(np.clip(isi * lum_per_rate, 0, 1))
            complex_ = clip["light"] <= 0.1 or clip["speed_px_s"] >= 3000
            rows.append({"index": len(rows), "shard": 0, "texture": clip["photo"], "light": clip["light"],
                         "speed_px_s": clip["speed_px_s"], "lum_per_rate": lum_per_rate,
                         "complex": int(complex_), "clip": clip["clip"], "tick": c})
        if args.events:
            ticks = [r["tick"] for r in rows if r["clip"] == clip["clip"]]
            events += event_windows(spikes, args.events / f"{clip['clip']}.npz", ticks, args.every, reps[-len(ticks):])
    if not rows:
        raise SystemExit(f"{args.frames}: no window fits after a warm-up of {args.warmup} ticks")
    shard = args.out / "000"
    shard.mkdir(parents=True, exist_ok=False)
    spike = np.stack(reps)
    np.save(shard / "spike.npy", spike)
    # Without a DVS the event channels are zero: only networks that read spikes alone are fair.
    np.save(shard / "events.npy", np.stack(events) if args.events else np.zeros_like(spike))
    np.save(shard / "truth.npy", np.stack(truths).astype(np.float32))
    np.save(shard / "tfp.npy", np.stack(tfps).astype(np.float32))
    np.save(shard / "tfi.npy", np.stack(tfis).astype(np.float32))
    with open(args.out / "samples.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"{args.out}: {len(rows)} windows from {len(clips)} clips")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("frames", help="panned clips of held-out photos, one frame a tick")
    f.add_argument("--photos", type=pathlib.Path, required=True)
    f.add_argument("--out", type=pathlib.Path, required=True)
    f.add_argument("--clips", type=int, default=24)
    f.add_argument("--size", type=int, default=96)
    f.add_argument("--ticks", type=int, default=600)
    f.add_argument("--inside-from", type=int, default=380,
                   help="the view lies inside the photo from this tick on")
    f.add_argument("--speeds", type=float, nargs="+", default=[300.0, 1000.0, 3000.0])
    f.add_argument("--lights", type=float, nargs="+", default=[1.0, 0.25])
    f.add_argument("--seed", type=int, default=0)
    w = sub.add_parser("windows", help="a simulator's spikes as a `neuspike dataset` folder")
    w.add_argument("--frames", type=pathlib.Path, required=True)
    w.add_argument("--spikes", type=pathlib.Path, required=True)
    w.add_argument("--out", type=pathlib.Path, required=True)
    w.add_argument("--lum-per-rate", type=float, default=1.0,
                   help="the simulator's luminance per spike a tick at light 1")
    w.add_argument("--warmup", type=int, default=400, help="ticks left out at a clip's start")
    w.add_argument("--every", type=int, default=50, help="ticks between reference planes")
    w.add_argument("--events", type=pathlib.Path,
                   help="a folder of <clip>.npz events (t_ns, x, y, p, width, height) an event-camera "
                   "simulator made from the same frames: the fused networks' input")
    args = ap.parse_args()
    frames_cmd(args) if args.cmd == "frames" else windows_cmd(args)


if __name__ == "__main__":
    main()
