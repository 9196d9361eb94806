"""neuspike's DVS against v2e on the same frames: event counts, per-pixel agreement and speed.

Needs v2e (github.com/SensorsINI/v2e, MIT; `pip install -e` of its checkout, with PyTorch) and
the release `neuspike` binary. Both emulators run on one CPU thread, in the same run, on the same
frames: a held-out photo panned across a 346x260 DAVIS sensor, one frame a millisecond, its
intensities in [0.1, 1] so that both take plain logs (v2e is linear below 20 of 255).

    python scripts/v2e_compare.py --photo data/textures/test/rocket-00.png --frames 300

For each of v2e's two presets (`--dvs_params clean` and `noisy`), the same settings are given to
`neuspike frames-to-events` under its names (docs/camera.md maps them):

| v2e | neuspike |
|---|---|
| pos_thres, neg_thres | --theta-on, --theta-off |
| sigma_thres (absolute) | --theta-sigma (relative: sigma_thres / pos_thres) |
| cutoff_hz | --cutoff-hz |
| leak_rate_hz, leak_jitter_fraction | --leak-rate-hz, --leak-jitter (and --leak-start level: v2e starts every pixel's leak cycle at its first level) |
| shot_noise_rate_hz | --shot-noise-rate-hz |
| refractory_period_s | --refractory-ns |

Reported: ON and OFF counts, their ratio (neuspike / v2e), the correlation of the per-pixel
signed event counts, and each emulator's frames per second of emulation (loading and writing
excluded), with the speed ratio.
"""

import argparse
import json
import pathlib
import subprocess
import tempfile
import time

import numpy as np

PRESETS = ("clean", "noisy")
WIDTH, HEIGHT = 346, 260


def frames_of(photo: pathlib.Path, n: int, speed_px_s: float, dt_ns: int) -> np.ndarray:
    """`n` frames of `photo` (grayscale, scaled to [0.1, 1]) panned at `speed_px_s` to the right
    and a little down, bilinear."""
    from scipy.ndimage import map_coordinates
    from skimage.io import imread
    from skimage.transform import resize

    img = imread(photo).astype(np.float64)
    img = img.mean(2) if img.ndim == 3 else img
    img = (img - img.min()) / max(np.ptp(img), 1e-9)
    travel = speed_px_s * n * dt_ns * 1e-9
    side = int(max(WIDTH, HEIGHT) + 2 * travel + 8)
    img = 0.1 + 0.9 * resize(img, (side, side), order=3, anti_aliasing=True).clip(0, 1)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    out = np.empty((n, HEIGHT, WIDTH), np.float32)
    for k in range(n):
        dx = speed_px_s * k * dt_ns * 1e-9
        out[k] = map_coordinates(img, [yy + 4 + 0.3 * dx, xx + 4 + dx], order=1, mode="nearest")
    return out


def run_v2e(frames: np.ndarray, dt_ns: int, preset: str, seed: int) -> dict:
    import torch
    from v2ecore.emulator import EventEmulator

    torch.set_num_threads(1)
    torch.manual_seed(seed)
    probe = EventEmulator(device="cpu")
    probe.set_dvs_params(preset)
    keys = ("pos_thres", "neg_thres", "sigma_thres", "cutoff_hz", "leak_rate_hz", "shot_noise_rate_hz",
            "refractory_period_s", "leak_jitter_fraction", "noise_rate_cov_decades")
    params = {k: float(getattr(probe, k)) for k in keys}
    emu = EventEmulator(device="cpu", output_width=frames.shape[2], output_height=frames.shape[1], **params)
    counts = np.zeros(frames.shape[1:], np.int64)
    on = off = 0
    dn = frames.astype(np.float64) * 255.0
    wall = 0.0
    for k in range(len(frames)):
        start = time.perf_counter()
        ev = emu.generate_events(dn[k], k * dt_ns * 1e-9)
        wall += time.perf_counter() - start
        if ev is None or len(ev) == 0:
            continue
        x, y, p = ev[:, 1].astype(int), ev[:, 2].astype(int), ev[:, 3].astype(int)
        np.add.at(counts, (y, x), p)
        on += int((p > 0).sum())
        off += int((p < 0).sum())
    return {"on": on, "off": off, "counts": counts, "wall_s": wall, "params": params}


def run_neuspike(binary: str, frames_path: pathlib.Path, dt_ns: int, params: dict, seed: int,
                 out: pathlib.Path) -> dict:
    args = [
        binary, "frames-to-events", "--frames", str(frames_path), "--dt-ns", str(dt_ns), "--out", str(out),
        "--theta-on", str(params["pos_thres"]), "--theta-off", str(params["neg_thres"]),
        "--theta-sigma", str(params["sigma_thres"] / params["pos_thres"]),
        "--cutoff-hz", str(params["cutoff_hz"]), "--leak-rate-hz", str(params["leak_rate_hz"]),
        "--leak-jitter", str(params["leak_jitter_fraction"]), "--leak-start", "level",
        "--shot-noise-rate-hz", str(params["shot_noise_rate_hz"]),
        "--refractory-ns", str(int(round(params["refractory_period_s"] * 1e9))), "--seed", str(seed),
    ]
    summary = json.loads(subprocess.run(args, check=True, capture_output=True, text=True).stdout)
    data = np.loadtxt(out, skiprows=1, ndmin=2)
    counts = np.zeros((summary["height"], summary["width"]), np.int64)
    if len(data):
        p = np.where(data[:, 3] > 0, 1, -1)
        np.add.at(counts, (data[:, 2].astype(int), data[:, 1].astype(int)), p)
    return summary | {"counts": counts}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photo", type=pathlib.Path, required=True)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--dt-ns", type=int, default=1_000_000)
    ap.add_argument("--speed-px-s", type=float, default=100.0)
    ap.add_argument("--neuspike", default="./target/release/neuspike")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", type=pathlib.Path)
    args = ap.parse_args()
    frames = frames_of(args.photo, args.frames, args.speed_px_s, args.dt_ns)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        frames_path = pathlib.Path(tmp) / "frames.npy"
        np.save(frames_path, frames)
        print(f"{args.frames} frames of {WIDTH}x{HEIGHT}, {args.dt_ns / 1e6:g} ms apart, "
              f"{args.speed_px_s:g} px/s, from {args.photo.name}")
        print("| preset | v2e ON / OFF | neuspike ON / OFF | count ratio | per-pixel correlation "
              "| v2e frames/s | neuspike frames/s | speed ratio |")
        print("|---|---|---|---|---|---|---|---|")
        for preset in PRESETS:
            v = run_v2e(frames, args.dt_ns, preset, args.seed)
            n = run_neuspike(args.neuspike, frames_path, args.dt_ns, v["params"], args.seed,
                             pathlib.Path(tmp) / "events.txt")
            # Frame 0 only sets the state in both: T - 1 steps.
            v_fps = (args.frames - 1) / v["wall_s"]
            ratio = (n["on"] + n["off"]) / max(v["on"] + v["off"], 1)
            corr = float(np.corrcoef(v["counts"].ravel(), n["counts"].ravel())[0, 1])
            row = {"preset": preset, "v2e_on": v["on"], "v2e_off": v["off"], "neuspike_on": n["on"],
                   "neuspike_off": n["off"], "count_ratio": ratio, "pixel_correlation": corr,
                   "v2e_frames_per_s": v_fps, "neuspike_frames_per_s": n["frames_per_s"],
                   "speed_ratio": n["frames_per_s"] / v_fps, "v2e_params": v["params"]}
            rows.append(row)
            print(f"| {preset} | {v['on']:,} / {v['off']:,} | {n['on']:,} / {n['off']:,} | {ratio:.3f} "
                  f"| {corr:.3f} | {v_fps:,.0f} | {n['frames_per_s']:,.0f} | {row['speed_ratio']:.1f}x |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
