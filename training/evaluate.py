"""Scores trained models and the classical baselines on a held-out `neuspike dataset` set, split
into normal and complex (dark or fast) scenes and by light scale, with REFERENCE.md's PSNR and SSIM.

    python training/evaluate.py --test data/test runs/fused-8.pt runs/spike-8.pt --json eval.json

A model is a training checkpoint (`.pt`) or an exported network (`.onnx`, run by onnxruntime one
sample at a time: how a shipped model is scored against a retrained one on the same set).

Each model's rate is turned into luminance with the sample's calibration (`lum_per_rate`; an
event-only model predicts luminance itself) and clipped to [0, 1], exactly as the infer node does; TFP (whole window) and TFI come from the set.
"""

import argparse
import json
import pathlib

import numpy as np
import torch

import data
from neuspike_net import NeuSpikeNet


def load_model(path: pathlib.Path) -> tuple[NeuSpikeNet, dict]:
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    cfg = ckpt["config"]
    model = NeuSpikeNet(
        base=cfg["base"],
        channels=cfg["channels"],
        mode=cfg["mode"],
        gated=cfg.get("gated", False),
        features=cfg.get("features", "full"),
    )
    model.load_state_dict(ckpt["state"])
    return model.eval(), cfg


@torch.no_grad()
def predict(model: NeuSpikeNet, split: data.Split, batch: int = 32) -> np.ndarray:
    frames = []
    for i in range(0, len(split), batch):
        idx = torch.arange(i, min(i + batch, len(split)))
        out = model(*split.inputs(model.inputs(), idx))
        lum = (out * model.gain(split.lum_per_rate[idx])).clamp(0, 1)
        frames.append(lum[:, 0].numpy())
    return np.concatenate(frames)


def predict_onnx(path: pathlib.Path, split: data.Split) -> np.ndarray:
    """An exported model's luminance frames: its inputs by name (`spike`, `events`), its output
    `rate` (times `lum_per_rate`) or `luminance`, clipped to [0, 1] as the infer node does."""
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    output = session.get_outputs()[0].name
    if output not in ("rate", "luminance") or not set(names) <= {"spike", "events"}:
        raise SystemExit(f"{path}: inputs {names}, output {output}: not a NeuSpike-Net export")
    frames = []
    for i in range(len(split)):
        feeds = {n: getattr(split, n)[i : i + 1].float().numpy() for n in names}
        out = session.run([output], feeds)[0][0, 0]
        gain = float(split.lum_per_rate[i]) if output == "rate" else 1.0
        frames.append(np.clip(out * gain, 0, 1))
    return np.stack(frames)


def after_gain(frames: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """docs/definitions.md's "PSNR after gain": each frame scaled by its least-squares gain
    `k = sum(x g) / sum(x x)` against the truth (1 for an all-zero frame), clipped to [0, 1]."""
    x = frames.astype(np.float64)
    xx = (x * x).sum(axis=(1, 2))
    xg = (x * truth).sum(axis=(1, 2))
    k = np.where(xx > 0, xg / np.where(xx > 0, xx, 1.0), 1.0)
    return np.clip(x * k[:, None, None], 0, 1).astype(np.float32)


def score(frames: np.ndarray, split: data.Split, gain: bool = False) -> dict:
    truth = split.truth[:, 0].numpy()
    if gain:
        frames = after_gain(frames, truth)
    p = np.array([data.psnr(f, t) for f, t in zip(frames, truth)])
    s = np.array([data.ssim(f, t) for f, t in zip(frames, truth)])
    groups = {"all": np.ones(len(split), bool), "normal": ~split.complex, "complex": split.complex}
    light = np.array([float(r["light"]) for r in split.rows])
    for v in sorted(set(light)):
        groups[f"light {v:g}"] = light == v
    return {g: {"psnr": float(p[m].mean()), "ssim": float(s[m].mean()), "n": int(m.sum())} for g, m in groups.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--test", type=pathlib.Path, required=True)
    ap.add_argument("--json", type=pathlib.Path)
    ap.add_argument(
        "--after-gain",
        action="store_true",
        help="score every method (TFP and TFI too) after each frame's least-squares gain against the truth",
    )
    ap.add_argument("models", type=pathlib.Path, nargs="*")
    args = ap.parse_args()
    test = data.load(args.test)
    g = args.after_gain
    results = {"tfp": score(test.tfp, test, g), "tfi": score(test.tfi, test, g)}
    for path in args.models:
        if path.suffix == ".onnx":
            results[path.stem] = score(predict_onnx(path, test), test, g) | {"config": {"onnx": str(path)}}
            continue
        model, cfg = load_model(path)
        results[path.stem] = score(predict(model, test), test, g) | {"config": cfg}
    after = ", every frame after its least-squares gain" if g else ""
    print(f"held-out: {args.test} ({len(test)} samples, {int(test.complex.sum())} complex{after})")
    print("| method | PSNR all | PSNR normal | PSNR complex | SSIM all | SSIM normal | SSIM complex |")
    print("|---|---|---|---|---|---|---|")
    for name, r in results.items():
        a, n, c = r["all"], r["normal"], r["complex"]
        print(
            f"| {name} | {a['psnr']:.2f} | {n['psnr']:.2f} | {c['psnr']:.2f} "
            f"| {a['ssim']:.3f} | {n['ssim']:.3f} | {c['ssim']:.3f} |"
        )
    lights = [g for g in next(iter(results.values())) if g.startswith("light ")]
    print("\nPSNR per light scale:\n")
    print("| method | " + " | ".join(lights) + " |")
    print("|---|" + "---|" * len(lights))
    for name, r in results.items():
        print(f"| {name} | " + " | ".join(f"{r[g]['psnr']:.2f}" for g in lights) + " |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
