"""Writes a model's card, `models/<name>.md`, from what was measured: the export's config
(`models/<name>.json`), the held-out scores (`evaluate.py --json`), tract's latency
(`neuspike bench-model`, run here) and onnxruntime's (`bench_ort.py`, run here) at 256x400 on 1
and 2 threads, in the same run so that the ratio compares like with like.

    python training/card.py models/neuspike-fused-8.onnx --eval runs/eval.json --run fused-8

Other runs of the same configuration in the evaluation (another seed or device) are listed as the
spread a retraining gives; runs of the same width and mode trained without the auxiliary loss
measure its effect. `training/summary.py` tabulates every run.
"""

import argparse
import json
import pathlib
import re
import subprocess

import bench_ort

ARCH = {
    "fused": "both paths (texture: spike representation; motion: event integration), fused by the "
    "feature fusion module after each encoder layer",
    "spike": "the texture path alone (spike representation); the paper's spike-only ablation",
    "event": "the motion path alone (event integration); the paper's event-only ablation",
}


def tract_times(model: str, threads: str, runs: int) -> tuple[dict[int, float], dict[int, str]]:
    out = subprocess.run(
        ["./target/release/neuspike", "bench-model", model, "--height", "256", "--width", "400",
         "--threads", threads, "--runs", str(runs)],
        check=True, capture_output=True, text=True,
    ).stdout
    found = re.findall(r"threads (\d+): median ([\d.]+) ms.*?(\w+) convolutions", out)
    return {int(t): float(ms) for t, ms, _ in found}, {int(t): c for t, _, c in found}


def recipe(cfg: dict) -> tuple:
    """What makes two runs the same configuration, seed and device aside."""
    return cfg["base"], cfg["mode"], cfg["aux"], cfg["steps"], "val" in cfg, cfg.get("l2", "mean"), cfg.get("gated", False)


def l2_text(cfg: dict) -> str:
    """The L2 term, as `train.py --l2` chose it."""
    if cfg.get("l2", "mean") == "psnr":
        return ("L2 on luminance, each sample's weighted by 1 / (its MSE + 1e-6) and the weights "
                "normalised (the gradient of the mean PSNR, at plain L2's scale)")
    return "L2 on luminance"


def same(a: dict, b: dict, *keys: str) -> bool:
    return all(a.get(k) == b.get(k) for k in keys)


def mean_row(runs: list[dict]) -> dict:
    return {g: {m: sum(r[g][m] for r in runs) / len(runs) for m in ("psnr", "ssim")} for g in ("normal", "complex")}


def device(cfg: dict) -> str:
    if cfg["device"] == "cuda":
        return "one H100 GPU shared by several runs at once (models/README.md)"
    return f"{cfg['device']} ({cfg['cpu_seconds']:,.0f} CPU-seconds)"


def row(name: str, r: dict) -> str:
    n, c = r["normal"], r["complex"]
    return f"| {name} | {n['psnr']:.2f} | {c['psnr']:.2f} | {n['ssim']:.3f} | {c['ssim']:.3f} |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", type=pathlib.Path)
    ap.add_argument("--eval", type=pathlib.Path, required=True)
    ap.add_argument("--run", required=True, help="the model's entry in the evaluation")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--note", default="", help="a line added to the training section")
    ap.add_argument("--speed-note", default="", help="a paragraph added to the speed section")
    args = ap.parse_args()
    cfg = json.loads(args.model.with_suffix(".json").read_text())
    ev = json.loads(args.eval.read_text())
    me = ev[args.run]
    tract, conv = tract_times(str(args.model), "1,2", args.runs)
    ort_ms = {t: bench_ort.time_model(str(args.model), 256, 400, t, args.runs)["median_ms"] for t in (1, 2)}
    best = max(("tfp", "tfi"), key=lambda m: ev[m]["complex"]["psnr"])
    best_n = max(("tfp", "tfi"), key=lambda m: ev[m]["normal"]["psnr"])
    name = args.model.stem
    n_all = me["all"]["n"]
    lines = [
        f"# {name}",
        "",
        f"NeuSpike-Net, {cfg['mode']} (base width {cfg['base']}): {ARCH[cfg['mode']]}. "
        f"{cfg['parameters']:,} parameters; ONNX opset {cfg['opset']}, {cfg['onnx_mb']} MB, inputs "
        f"{', '.join('`' + i + '`' for i in cfg['inputs'])} (`[1, {cfg['channels']}, H, W]`, H and W "
        "multiples of 8: the infer node pads), output "
        + ("`rate` (spikes per tick; the node multiplies by `lum_per_rate`). "
           if cfg.get("output", "rate") == "rate"
           else "`luminance` (events carry no absolute level, so this model cannot use the spike "
           "camera's calibration: it predicts luminance itself). ")
        + "Built by `training/neuspike_net.py`: head convolution, 3 stride-2 encoder "
        "layers doubling the width, channel and spatial attention fusion after each (Eq. 11-12), 2 "
        + ("residual blocks, 3 transposed-convolution decoder layers with the fused skips, a depthwise "
           "convolution and a sigmoid. " if cfg.get("features", "full") == "full" else
           "residual blocks, 2 transposed-convolution decoder layers with the fused skips down to half "
           "resolution, a 3x3 convolution to the 4 pixels of each 2x2 block (a sub-pixel shuffle, "
           "`DepthToSpace`) plus a 1x1 convolution of each path's full-resolution head feature, and a "
           "sigmoid (`--features half`). ")
        + "The channel maximum of the spatial attention is exported as a "
        "tree of `Max` (`training/onnx_passes.py`, exact).",
        "",
        "## Training",
        "",
        f"- Data: `neuspike dataset --split train` ({cfg['train_samples']:,} samples of 64x64, 5 light "
        "scales x 5 speeds, 120 a cell; half the textures procedural, half crops of 13 scikit-image "
        "photos; see training/README.md).",
        f"- {cfg['steps']:,} steps of {cfg['batch']} samples (Adam, one-cycle, max lr {cfg['lr']}), "
        f"seed {cfg['seed']}, the 8 flips and quarter turns; {cfg['train_seconds'] / 60:.1f} min wall on "
        f"{device(cfg)}."
        + (f" The weights kept are those of step {cfg['best_step']:,}, the best mean PSNR "
           f"({cfg['best_val_psnr']:.2f} dB) on a validation set scored every 500 steps "
           f"({cfg['val_samples']} samples of 96x96 made like the training set with `--seed 1`; "
           "never the held-out set)." if "val" in cfg else ""),
        f"- Loss: {l2_text(cfg)} + {cfg['aux_weight']} x {cfg['aux']} "
        "(the paper's VGG perceptual term needs pretrained weights that cannot be downloaded here)."
        if cfg["aux"] != "none"
        else f"- Loss: {l2_text(cfg)} only (the comparison run for the auxiliary term).",
        f"- PyTorch {cfg['torch']}; exported and checked against onnxruntime (max |diff| < 1e-4) by "
        "`training/export.py`; `models/" + name + ".ref/` is the reference tract must reproduce "
        "(`stages/reconstruction/tests/learned.rs`).",
    ] + ([f"- {args.note}"] if args.note else []) + [
        "",
        "## Accuracy (held-out set)",
        "",
        f"`neuspike dataset --split test`: {n_all} samples of 96x96 ({me['normal']['n']} normal, "
        f"{me['complex']['n']} complex: light <= 0.1 or speed >= 3,000 px/s), textures never seen in "
        "training (other procedural seeds; photos chelsea, coins, gravel, rocket). PSNR (dB) and "
        "SSIM as docs/definitions.md defines them, luminance clipped to [0, 1].",
        "",
        "| method | PSNR normal | PSNR complex | SSIM normal | SSIM complex |",
        "|---|---|---|---|---|",
        row(f"**{name}**", me),
        row("TFP (33 planes)", ev["tfp"]),
        row("TFI", ev["tfi"]),
    ]
    repeats = [(k, v) for k, v in ev.items()
               if k != args.run and "config" in v and recipe(v["config"]) == recipe(me["config"])]
    for k, v in repeats:
        c = v["config"]
        lines.append(row(f"same configuration, seed {c['seed']} on {c['device']} ({k})", v))
    lines += [
        "",
        f"Margin over the best classical method: {me['complex']['psnr'] - ev[best]['complex']['psnr']:+.2f} dB "
        f"on complex scenes ({best}), {me['normal']['psnr'] - ev[best_n]['normal']['psnr']:+.2f} dB on normal "
        f"ones ({best_n}).",
    ]
    if repeats:
        lines += [
            "",
            "The shipped model is the seed-0 run, chosen before scoring; the other runs of the same "
            "configuration show how much retraining alone moves the scores.",
        ]
    if me["config"]["aux"] != "none":
        base_runs = [v for v in ev.values() if "config" in v and recipe(v["config"]) == recipe(me["config"])]
        noaux = [v for v in ev.values() if "config" in v
                 and recipe(v["config"]) == recipe(me["config"] | {"aux": "none"})]
        if noaux:
            a, b = mean_row(base_runs), mean_row(noaux)
            lines += [
                "",
                f"Effect of the auxiliary loss (mean of {len(base_runs)} runs with it, {len(noaux)} without, "
                f"same width and mode): PSNR normal / complex {a['normal']['psnr']:.2f} / "
                f"{a['complex']['psnr']:.2f} dB against {b['normal']['psnr']:.2f} / {b['complex']['psnr']:.2f}, "
                f"SSIM {a['normal']['ssim']:.3f} / {a['complex']['ssim']:.3f} against "
                f"{b['normal']['ssim']:.3f} / {b['complex']['ssim']:.3f}.",
            ]
    lines += ["", "Every run, the ablations and the widths side by side: [models/README.md](README.md)."]
    lines += [
        "",
        "## Speed (256x400, this machine, one run)",
        "",
        "| threads | tract (ms) | tract convolutions | onnxruntime (ms) | tract / onnxruntime |",
        "|---|---|---|---|---|",
    ]
    for t in (1, 2):
        lines.append(f"| {t} | {tract[t]:.1f} | {conv[t]} | {ort_ms[t]:.1f} | {tract[t] / ort_ms[t]:.2f}x |")
    lines += [
        "",
        f"`neuspike bench-model models/{name}.onnx --height 256 --width 400` and "
        f"`python training/bench_ort.py models/{name}.onnx --height 256 --width 400`: median of "
        f"{args.runs} runs after a warm-up, the same input pattern. tract's convolutions are those the infer node's default "
        "`--conv auto` chose (it times each path, tract's direct convolution, im2col, and neuspike's "
        "3x3 kernel on the wide layers, on the first frame and keeps the fastest) "
        "with mimalloc, and its time includes copying the inputs into the padded tensor, as the node "
        "does; onnxruntime's does not.",
        "",
    ] + ([args.speed_note, ""] if args.speed_note else [])
    args.model.with_suffix(".md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
