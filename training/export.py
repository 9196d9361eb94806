"""Exports a trained NeuSpike-Net to ONNX (opset 17, dynamic height and width), checks
onnxruntime against PyTorch, and writes the reference the Rust tests replay with tract.

    python training/export.py runs/fused-8.pt --test data/test --out models/neuspike-fused-8.onnx

Beside `<name>.onnx` it writes `<name>.ref/`: a small real input taken from the held-out set
(`spike.npy` and/or `events.npy`, `[1, 32, 16, 24]` float32) and PyTorch's output for it
(`rate.npy`, or `luminance.npy` for an event-only model, `[1, 1, 16, 24]`), plus `<name>.json`
(the training config, for the card). The export fails when onnxruntime differs from PyTorch by more than 1e-4 on that input or on a whole
held-out sample.
"""

import argparse
import json
import pathlib

import numpy as np
import onnx
import onnxruntime as ort
import torch

import data
import onnx_passes
from evaluate import load_model
from neuspike_net import STRIDE

TOLERANCE = 1e-4
REF_HW = (16, 24)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoint", type=pathlib.Path)
    ap.add_argument("--test", type=pathlib.Path, required=True)
    ap.add_argument("--out", type=pathlib.Path, required=True)
    ap.add_argument("--sample", type=int, default=5, help="held-out sample the reference is cut from")
    args = ap.parse_args()
    model, cfg = load_model(args.checkpoint)
    names = model.inputs()
    test = data.load(args.test)
    full = [x.numpy() for x in test.inputs(names, torch.tensor([args.sample]))]
    h, w = (full[0].shape[2] // STRIDE) * STRIDE, (full[0].shape[3] // STRIDE) * STRIDE
    full = [np.ascontiguousarray(x[:, :, :h, :w]) for x in full]
    ref = [np.ascontiguousarray(x[:, :, : REF_HW[0], : REF_HW[1]]) for x in full]

    args.out.parent.mkdir(parents=True, exist_ok=True)
    dynamic = {n: {2: "height", 3: "width"} for n in names} | {model.output: {2: "height", 3: "width"}}
    torch.onnx.export(
        model,
        tuple(torch.from_numpy(x) for x in ref),
        str(args.out),
        input_names=names,
        output_names=[model.output],
        dynamic_axes=dynamic,
        opset_version=17,
        dynamo=False,
    )
    # Exact rewrites that make tract faster (onnx_passes.py); the check below covers them.
    proto = onnx.load(str(args.out))
    print(f"onnx passes: {onnx_passes.optimise(proto)}")
    onnx.save(proto, str(args.out))
    session = ort.InferenceSession(str(args.out), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        for xs in (ref, full):
            want = model(*(torch.from_numpy(x) for x in xs)).numpy()
            got = session.run([model.output], dict(zip(names, xs)))[0]
            diff = float(np.abs(got - want).max())
            print(f"onnxruntime vs PyTorch at {xs[0].shape[2]}x{xs[0].shape[3]}: max |diff| {diff:.2e}")
            if diff > TOLERANCE:
                raise SystemExit(f"export: onnxruntime differs from PyTorch by {diff} > {TOLERANCE}")
            if xs is ref:
                ref_out = want
    folder = args.out.with_suffix(".ref")
    folder.mkdir(exist_ok=True)
    for n, x in zip(names, ref):
        np.save(folder / f"{n}.npy", x.astype(np.float32))
    np.save(folder / f"{model.output}.npy", ref_out.astype(np.float32))
    size_mb = args.out.stat().st_size / 2**20
    cfg |= {"onnx": args.out.name, "onnx_mb": round(size_mb, 2), "inputs": names, "output": model.output, "opset": 17}
    args.out.with_suffix(".json").write_text(json.dumps(cfg, indent=1) + "\n")
    print(f"{args.out}: {size_mb:.2f} MB, inputs {names}, reference in {folder}")


if __name__ == "__main__":
    main()
