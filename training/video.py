"""Real video for the networks: clips of 20 kHz ticks made from real footage, which
`neuspike dataset --clips` turns into samples with neuspike's cameras.

    python training/video.py clips --split train --size 64 --samples 3000 --out data/clips-train
    ./target/release/neuspike dataset --split train --clips data/clips-train --size 64 \\
        --randomise-camera --out data/video-train

The videos are those of `training/video.csv` (the manifest: each clip's scene, source, licence
and split), read from `--videos` (`../shared/data/video` by default, where it exists; any folders
holding the manifest's files, searched in order). `--manifest` names other manifests instead:
`training/video-more.csv` lists 11 more clips for training, each with the repository and commit
to fetch it from. Train, validation and test are split by source video: no frame of a test
video, nor of a near-duplicate, is in training or validation.

    python training/video.py clips --split train --manifest training/video.csv \
        training/video-more.csv --videos ../shared/data/video more-video --weight-cap 300 \
        --size 128 --samples 1500 --seed 7 --out data/clips-train-128-more

One sample is a window of 33 ticks around a real frame `c` (the reference plane 16 is `c`
itself, so the ground truth is a real frame, not an interpolated one). The ticks between real
frames come from optical flow (OpenCV's DIS, medium preset, on the video at a working scale of at
most 288 pixels on the short side): the frame at `tau = a + f` between frames `a` and `b = a + 1`
is `(1 - f) I_a(x - f F_ab(x)) + f I_b(x - (1 - f) F_ba(x))`, each flow read where the frame is
made (the linear-motion approximation; occlusions are blended, not resolved). A real frame
interval spans `K` ticks, chosen per sample so that the motion in the crop (the 95th percentile of
the flow's length there, so that a small object moving fast over a still background is bounded
too) moves at one of the grid's speeds (0, 300, 1,000, 3,000, 8,000 px/s at
20 kHz; `K` at least 2, so a fast sample of a slow video is slower than its cell: the speed
written is the one the clip has). Speed 0 holds the frame still.

Each sample also draws: the crop (`size x size` at the working scale), a horizontal flip, the
direction of time, and the gamma that turns the video's 8-bit grey (Rec. 709 weights on the
stored values) into light, `I = max(g^gamma, 0.01)` with `gamma` uniform in [1, 2.2] (video is
gamma-encoded; how it maps to a scene's radiance is unknown, so the network sees both ends).
Deterministic for `--seed`.

Output: `<out>/<index>.npy` (float32 `[34, size, size]`, frame `j` at tick `j`, `dt_ns` 50,000)
and `<out>/clips.csv` (`file,source,frame,speed_px_s,angle_deg,dt_ns` and how it was drawn).
"""

import argparse
import collections
import csv
import math
import pathlib

import numpy as np

MANIFEST = pathlib.Path(__file__).with_name("video.csv")
DEFAULT_VIDEOS = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data" / "video"
RATE_HZ = 20_000.0
PERIOD_NS = 50_000
WINDOW = 33
REF = WINDOW // 2
FRAMES = WINDOW + 1
SPEEDS_PX_S = [0.0, 300.0, 1_000.0, 3_000.0, 8_000.0]
WORK_SHORT_SIDE = 288
MIN_TICKS_PER_FRAME = 2.0
FLOOR = 0.01
TICKS_PER_FRAME_CHOICES = [2, 5, 10, 25, 50]  # the divisors of `frames --every 50`
CUT = 0.12  # mean absolute grey change between frames above which a shot ends
FLOWS_KEPT = 64  # flows a video keeps (about 1.2 MB each at the working scale)


def manifest(split: str | None = None, paths: list[pathlib.Path] | None = None) -> list[dict]:
    """The rows of each manifest in `paths` (`training/video.csv` alone by default) in `split`,
    each with the manifest it came from as `"manifest"`."""
    rows = []
    for path in paths or [MANIFEST]:
        with open(path, newline="") as f:
            rows += [dict(r, manifest=str(path)) for r in csv.DictReader(f)]
    return [r for r in rows if split is None or r["split"] == split]


def find_video(row: dict, folders: list[pathlib.Path]) -> pathlib.Path:
    """The first of `folders` that holds `row`'s file; exits naming the file and its manifest."""
    for folder in folders:
        if (folder / row["file"]).exists():
            return folder / row["file"]
    where = ", ".join(str(f) for f in folders)
    raise SystemExit(f"{row['file']}: not found in {where} (see {row['manifest']} for where to get each clip)")


def sources(args) -> list[tuple[dict, pathlib.Path]]:
    """The manifests' rows in `args.split`, each with its file, every file found before any is
    read; exits when the split is empty or a file is missing."""
    rows = manifest(args.split, args.manifest)
    if not rows:
        names = ", ".join(str(m) for m in args.manifest or [MANIFEST])
        raise SystemExit(f"{names}: no video in split {args.split!r}")
    return [(r, find_video(r, args.videos)) for r in rows]


def light_of(grey: np.ndarray, gamma: float) -> np.ndarray:
    """The video's 8-bit grey in [0, 1] as light: `max(g^gamma, FLOOR)`, float32."""
    return np.maximum(np.clip(grey, 0.0, 1.0) ** gamma, FLOOR).astype(np.float32)


class Video:
    """One video at its working scale: grey frames in [0, 1], shots, flows on demand."""

    def __init__(self, path: pathlib.Path):
        import cv2

        self.cv2 = cv2
        cap = cv2.VideoCapture(str(path))
        grey = []
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            b, g, r = (frame[..., k].astype(np.float32) / 255.0 for k in range(3))
            y = 0.2126 * r + 0.7152 * g + 0.0722 * b
            h, w = y.shape
            s = min(1.0, WORK_SHORT_SIDE / min(h, w))
            if s < 1.0:
                y = cv2.resize(y, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)
            grey.append(y)
        if len(grey) < 2:
            raise SystemExit(f"{path}: {len(grey)} frames decoded (needs at least 2)")
        self.name = path.name
        self.frames = grey
        self.dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        # The flows of the last FLOWS_KEPT pairs asked for: a sample reads a few neighbouring
        # frames' flows several times; samples far apart share none (a long video's every flow
        # kept would take gigabytes). DIS gives the same flow when asked again.
        self.flows: collections.OrderedDict[tuple[int, int], np.ndarray] = collections.OrderedDict()
        # Shots: a frame whose mean absolute change from the one before exceeds CUT starts one.
        self.shot = np.zeros(len(grey), dtype=np.int64)
        for k in range(1, len(grey)):
            cut = float(np.mean(np.abs(grey[k] - grey[k - 1]))) > CUT
            self.shot[k] = self.shot[k - 1] + int(cut)

    def __len__(self) -> int:
        return len(self.frames)

    def flow(self, a: int, b: int) -> np.ndarray:
        """DIS flow from frame `a` to frame `b` ([H, W, 2], pixels), cached."""
        key = (a, b)
        if key in self.flows:
            self.flows.move_to_end(key)
        else:
            u8 = lambda k: (self.frames[k] * 255.0 + 0.5).astype(np.uint8)  # noqa: E731
            self.flows[key] = self.dis.calc(u8(a), u8(b), None)
            if len(self.flows) > FLOWS_KEPT:
                self.flows.popitem(last=False)
        return self.flows[key]

    def fastest(self, a: int, x0: int, y0: int, size: int) -> float:
        """The 95th percentile of the flow's length from frame `a` to `a + 1` over a crop."""
        fl = self.flow(a, a + 1)[y0 : y0 + size, x0 : x0 + size]
        return float(np.percentile(np.hypot(fl[..., 0], fl[..., 1]), 95))

    def same_shot(self, a: int, b: int) -> bool:
        return 0 <= a and b < len(self) and self.shot[a] == self.shot[b]

    def at(self, tau: float, x0: int, y0: int, size: int) -> np.ndarray:
        """The `size` x `size` crop at `(x0, y0)` of the frame at real time `tau` (frames)."""
        cv2 = self.cv2
        a = math.floor(tau)
        f = tau - a
        crop = (slice(y0, y0 + size), slice(x0, x0 + size))
        if f < 1e-9:
            return self.frames[a][crop].copy()
        b = a + 1
        gx, gy = np.meshgrid(np.arange(x0, x0 + size, dtype=np.float32), np.arange(y0, y0 + size, dtype=np.float32))
        fab, fba = self.flow(a, b)[crop], self.flow(b, a)[crop]
        wa = cv2.remap(self.frames[a], gx - f * fab[..., 0], gy - f * fab[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        wb = cv2.remap(
            self.frames[b], gx - (1 - f) * fba[..., 0], gy - (1 - f) * fba[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
        )
        return (1 - f) * wa + f * wb


def draw_sample(video: Video, rng: np.random.Generator, size: int, speed_px_s: float, tries: int = 6):
    """A clip of FRAMES ticks from `video` at about `speed_px_s`: the frames, and what was drawn."""
    h, w = video.frames[0].shape
    if h < size or w < size:
        raise SystemExit(f"{video.name}: {w}x{h} at the working scale is smaller than --size {size}")
    target = speed_px_s / RATE_HZ  # pixels a tick
    best = None
    for _ in range(tries):
        c = int(rng.integers(1, len(video) - 1))
        x0, y0 = int(rng.integers(0, w - size + 1)), int(rng.integers(0, h - size + 1))
        if not video.same_shot(c, c + 1):
            continue
        fl = video.flow(c, c + 1)[y0 : y0 + size, x0 : x0 + size]
        angle = math.degrees(math.atan2(float(np.median(fl[..., 1])), float(np.median(fl[..., 0]))))
        if target == 0.0:
            best = (c, x0, y0, math.inf, 0.0, angle)
            break
        # The fast end of the crop's motion over the frames the window spans sets the step (a
        # small object moving fast over a still background must not cross pixels a tick).
        span, d, ok = 1, 0.0, True
        for _ in range(3):
            if not (video.same_shot(c - span, c) and video.same_shot(c, c + span)):
                ok = False
                break
            d = max(video.fastest(a, x0, y0, size) for a in range(c - span, c + span))
            k = max(d / target, MIN_TICKS_PER_FRAME)
            # The window's real frames (and one more each side) must lie in one shot.
            need = math.ceil((REF + 1) / k) + 1
            if need <= span:
                break
            span = need
        if not ok:
            continue
        cand = (c, x0, y0, k, d / k, angle)
        if best is None or abs(math.log((cand[4] + 1e-6) / target)) < abs(math.log((best[4] + 1e-6) / target)):
            best = cand
        if d / target >= MIN_TICKS_PER_FRAME:
            break
    if best is not None and math.isfinite(best[3]) and best[3] < MIN_TICKS_PER_FRAME:
        return None
    if best is None:
        return None
    c, x0, y0, k, px_tick, angle = best
    backward = bool(rng.random() < 0.5) and math.isfinite(k)
    flip = bool(rng.random() < 0.5)
    gamma = float(rng.uniform(1.0, 2.2))
    out = np.empty((FRAMES, size, size), dtype=np.float32)
    for j in range(FRAMES):
        if math.isinf(k):
            tau = float(c)
        else:
            dt = (j - REF) / k
            tau = c - dt if backward else c + dt
        out[j] = video.at(tau, x0, y0, size)
    if flip:
        out = out[:, :, ::-1]
        angle = 180.0 - angle
    if backward:
        angle += 180.0
    out = light_of(out, gamma)
    info = dict(
        frame=c,
        speed_px_s=px_tick * RATE_HZ,
        angle_deg=(angle + 360.0) % 360.0,
        ticks_per_frame=k,
        x0=x0,
        y0=y0,
        flip=int(flip),
        backward=int(backward),
        gamma=gamma,
    )
    return np.ascontiguousarray(out), info


def frames_cmd(args) -> None:
    """Long clips for other simulators (`training/outside.py windows` cuts them): `--ticks` ticks
    at a fixed number of ticks a real frame, chosen from `TICKS_PER_FRAME_CHOICES` so that the
    crop's motion is near the clip's speed and every scored window's reference tick (`--warmup +
    16`, then every `--every`) is a real frame; the light is the clip's."""
    import json

    found = sources(args)
    out = args.out
    out.mkdir(parents=True, exist_ok=False)
    rng = np.random.default_rng(args.seed)
    clips_made = []
    ref0 = args.warmup + REF
    for r, path in found:
        video = Video(path)
        h, w = video.frames[0].shape
        for k in range(args.per_video):
            speed = args.speeds[k % len(args.speeds)]
            light = args.lights[(k // len(args.speeds)) % len(args.lights)]
            target = speed / RATE_HZ
            for _ in range(20):
                x0, y0 = int(rng.integers(0, w - args.size + 1)), int(rng.integers(0, h - args.size + 1))
                c = int(rng.integers(1, len(video) - 1))
                d = video.fastest(c, x0, y0, args.size)
                # Ticks a frame that divide the window spacing: real frames at every reference;
                # the one nearest the speed that the video holds.
                fits = [
                    q
                    for q in sorted(TICKS_PER_FRAME_CHOICES, key=lambda q: abs(math.log((d / q + 1e-6) / target)))
                    if math.floor(c - ref0 / q) >= 0
                    and math.ceil(c + (args.ticks - 1 - ref0) / q) < len(video)
                    and video.same_shot(math.floor(c - ref0 / q), math.ceil(c + (args.ticks - 1 - ref0) / q))
                ]
                if fits:
                    kpf = fits[0]
                    break
            else:
                print(f"{r['file']}: no {speed:.0f} px/s clip fits; skipped")
                continue
            clip = np.stack([video.at(c + (j - ref0) / kpf, x0, y0, args.size) for j in range(args.ticks)])
            gamma = float(rng.uniform(1.0, 2.2))
            clip = light * light_of(clip, gamma)
            name = f"{pathlib.Path(r['file']).stem}-{k:02d}"
            np.save(out / f"{name}.npy", clip.astype(np.float32))
            clips_made.append(
                {"clip": name, "photo": r["file"], "speed_px_s": round(d / kpf * RATE_HZ, 1), "light": light,
                 "ticks_per_frame": kpf, "frame": c, "gamma": round(gamma, 3), "x0": x0, "y0": y0}
            )
            print(f"{name}: {d / kpf * RATE_HZ:.0f} px/s, {kpf} ticks a frame, light {light}", flush=True)
    (out / "clips.json").write_text(json.dumps(clips_made, indent=1))
    print(f"{out}: {len(clips_made)} clips of {args.ticks} ticks at {args.size}x{args.size}")


def clips(args) -> None:
    if args.weight_cap is not None and args.weight_cap < 1:
        raise SystemExit(f"--weight-cap {args.weight_cap}: at least 1 frame")
    out = args.out
    if out.exists():
        raise SystemExit(f"{out}: already exists (a new folder is made for the clips)")
    found = sources(args)
    out.mkdir(parents=True)
    videos = []
    for r, path in found:
        videos.append(Video(path))
        print(f"{r['file']}: {len(videos[-1])} frames, {videos[-1].shot[-1] + 1} shots", flush=True)
    # Samples in proportion to each video's frames (at most `--weight-cap` counted: a long clip
    # of little motion does not crowd out the others), at least a few each.
    frames = np.array([min(len(v), args.weight_cap or len(v)) for v in videos], dtype=np.float64)
    rng = np.random.default_rng(args.seed)
    with open(out / "clips.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["file", "source", "frame", "speed_px_s", "angle_deg", "dt_ns", "ticks_per_frame", "x0", "y0", "flip", "backward", "gamma"])
        i = 0
        while i < args.samples:
            v = videos[int(rng.choice(len(videos), p=frames / frames.sum()))]
            # The Rust side draws the light of sample i as the grid's (i mod 5): the speeds cycle
            # over each run of five so that every (light, speed) pair comes round.
            speed = SPEEDS_PX_S[(i // 5) % len(SPEEDS_PX_S)]
            got = draw_sample(v, rng, args.size, speed)
            if got is None:
                continue
            clip, info = got
            name = f"{i:05d}.npy"
            np.save(out / name, clip)
            w.writerow(
                [name, v.name, info["frame"], f"{info['speed_px_s']:.1f}", f"{info['angle_deg']:.1f}", PERIOD_NS]
                + [f"{info['ticks_per_frame']:.3f}", info["x0"], info["y0"], info["flip"], info["backward"], f"{info['gamma']:.3f}"]
            )
            i += 1
    print(f"{out}: {args.samples} clips of {FRAMES} ticks at {args.size}x{args.size}")


def add_sources(p: argparse.ArgumentParser) -> None:
    p.add_argument("--manifest", type=pathlib.Path, nargs="+", default=None,
                   help="manifests of videos (default: training/video.csv); training/video-more.csv lists more")
    p.add_argument("--videos", type=pathlib.Path, nargs="+", default=[DEFAULT_VIDEOS],
                   help="folders holding the manifests' files, searched in order")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("clips", help="clips of ticks around real frames, for `neuspike dataset --clips`")
    c.add_argument("--split", required=True, choices=["train", "val", "test"])
    add_sources(c)
    c.add_argument("--size", type=int, default=64)
    c.add_argument("--samples", type=int, default=1000)
    c.add_argument("--weight-cap", type=int, default=None,
                   help="count at most this many frames of a video when sharing the samples out (default: all)")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--out", type=pathlib.Path, required=True)
    f = sub.add_parser("frames", help="long clips, one frame a tick, for other simulators (training/outside.py)")
    f.add_argument("--split", default="test", choices=["train", "val", "test"])
    add_sources(f)
    f.add_argument("--size", type=int, default=96)
    f.add_argument("--ticks", type=int, default=600)
    f.add_argument("--warmup", type=int, default=400, help="as outside.py windows --warmup")
    f.add_argument("--per-video", type=int, default=6)
    f.add_argument("--speeds", type=float, nargs="+", default=[300.0, 1000.0, 3000.0])
    f.add_argument("--lights", type=float, nargs="+", default=[1.0, 0.25])
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--out", type=pathlib.Path, required=True)
    ls = sub.add_parser("list", help="the manifest: each video's split, scene and licence")
    ls.add_argument("--manifest", type=pathlib.Path, nargs="+", default=None)
    args = ap.parse_args()
    if args.cmd == "clips":
        clips(args)
    elif args.cmd == "frames":
        frames_cmd(args)
    else:
        for r in manifest(None, args.manifest):
            print(f"{r['split']:5} {r['file']:45} {r['place']:10} {r['content']} [{r['licence']}]")


if __name__ == "__main__":
    main()
