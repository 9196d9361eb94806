"""Times an ONNX model in onnxruntime (the reference runtime) exactly as `neuspike bench-model`
times it in tract: the same frame size padded to the stride, the same input pattern, one untimed
warm-up run, then the median of `--runs`, for each thread count.

    python training/bench_ort.py models/neuspike-fused-8.onnx --threads 1,2
"""

import argparse
import json
import time

import numpy as np
import onnxruntime as ort

STRIDE = 8


def pattern(c: int, h: int, w: int) -> np.ndarray:
    """`((7k + 3y + x) mod 17) / 16`, as bench_model.rs fills its inputs."""
    k, y, x = np.meshgrid(np.arange(c), np.arange(h), np.arange(w), indexing="ij")
    return (((k * 7 + y * 3 + x) % 17) / 16.0).astype(np.float32)[None]


def time_model(path: str, height: int, width: int, threads: int, runs: int) -> dict:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    session = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])
    hp, wp = -(-height // STRIDE) * STRIDE, -(-width // STRIDE) * STRIDE
    feeds = {i.name: pattern(i.shape[1], hp, wp) for i in session.get_inputs()}
    session.run(None, feeds)
    ms = []
    for _ in range(runs):
        start = time.perf_counter()
        session.run(None, feeds)
        ms.append((time.perf_counter() - start) * 1e3)
    ms.sort()
    return {"threads": threads, "median_ms": ms[len(ms) // 2], "min_ms": ms[0], "runs": runs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model")
    ap.add_argument("--height", type=int, default=250)
    ap.add_argument("--width", type=int, default=400)
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args()
    out = [time_model(args.model, args.height, args.width, int(t), args.runs) for t in args.threads.split(",")]
    for t in out:
        print(f"threads {t['threads']}: median {t['median_ms']:.2f} ms, min {t['min_ms']:.2f} ms ({t['runs']} runs)")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
