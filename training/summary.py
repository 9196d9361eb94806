"""Tabulates every evaluated run (`evaluate.py --json`) by configuration: the widths, the paper's
Table 2 ablations (fused, spike-only, event-only) and the auxiliary loss, each configuration's
runs (seeds, devices) with their mean, against the classical baselines.

    python training/summary.py --eval runs/eval.json > models/RUNS.md
"""

import argparse
import json
import pathlib
from collections import defaultdict


def fmt(r: dict) -> str:
    n, c = r["normal"], r["complex"]
    return f"{n['psnr']:.2f} | {c['psnr']:.2f} | {n['ssim']:.3f} | {c['ssim']:.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--eval", type=pathlib.Path, required=True)
    args = ap.parse_args()
    ev = json.loads(args.eval.read_text())
    groups = defaultdict(list)
    for name, r in ev.items():
        if "config" in r:
            c = r["config"]
            l2 = c.get("l2", "mean")
            key = (c["mode"], c["base"], c["aux"], c["steps"], "val" in c, l2, c.get("gated", False),
                   c.get("camera", "paper"), c.get("init", ""), c.get("features", "full"),
                   # the data matters to the label only for a fine-tune (paths differ by machine)
                   c.get("train", "") if c.get("init") else "")
            groups[key].append((name, r))
    order = {"fused": 0, "spike": 1, "event": 2}
    print("| configuration | run | device | PSNR normal | PSNR complex | SSIM normal | SSIM complex |")
    print("|---|---|---|---|---|---|---|")
    for k in ("tfp", "tfi"):
        print(f"| {k.upper()} (classical) | | | {fmt(ev[k])} |")
    def key(g):
        mode, base, aux, steps, val, l2, gated, camera, init, features, _ = g[0]
        return order[mode], base, features, ["ssim", "grad", "none"].index(aux), bool(init), steps, val, l2, gated, camera

    for (mode, base, aux, steps, val, l2, gated, camera, init, features, train), runs in sorted(
        groups.items(), key=key
    ):
        label = f"{mode}, base {base}, aux {aux}, {steps / 1000:g}k steps" + (", best on validation" if val else "")
        # A fine-tune (`train.py --init`): where its weights started and what it trained on.
        label += f", fine-tuning `{init}` on `{train}`" if init else ""
        label += ", L2 weighted by 1/MSE" if l2 == "psnr" else ""
        label += ", motion path gated from 0" if gated else ""
        label += ", decoder to half resolution (`--features half`)" if features == "half" else ""
        label += {"paper": "", "random": ", cameras drawn at random",
                  "random, no clean share": ", cameras drawn at random, none clean"}.get(camera, f", {camera}")
        for name, r in sorted(runs, key=lambda x: (x[1]["config"]["seed"], x[0])):
            c = r["config"]
            print(f"| {label} | {name} (seed {c['seed']}) | {c['device']} | {fmt(r)} |")
        if len(runs) > 1:
            mean = {g: {m: sum(r[g][m] for _, r in runs) / len(runs) for m in ("psnr", "ssim")}
                    for g in ("normal", "complex")}
            print(f"| {label} | **mean of {len(runs)}** | | {fmt(mean)} |")


if __name__ == "__main__":
    main()
