"""Simulated training samples made on demand against the same samples read from disk.

For each crop size, makes N samples of ``neuspike.Samples`` (cameras drawn at random, as
``neuspike dataset --randomise-camera``) three ways, and reads them back from ``.npy`` shards
written in ``neuspike dataset``'s layout:

- ``batch``: ``Samples.batch`` of 32 indices, made side by side on the package's threads;
- ``one by one``: ``Samples[i]``, as a map-style ``Dataset`` in one worker asks;
- ``disk``: ``numpy.load`` of the shards (the page cache warm: the best case for disk).

Prints samples per second for each, on 1 thread and on all cores. Run from anywhere with the
package installed (``pip install ./python``)::

    python3 scripts/samples_rate.py [--sizes 64 128] [--samples 256]
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

import neuspike as ns

ARRAYS = ("spike", "events", "truth", "tfp", "tfi")


def rate(n, seconds):
    return n / seconds if seconds > 0 else float("inf")


def timed(f):
    t = time.perf_counter()
    out = f()
    return out, time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--samples", type=int, default=256, help="samples per size")
    ap.add_argument("--shard", type=int, default=64, help="samples per .npy shard on disk")
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    print("| crop | threads | batch samples/s | one by one samples/s | disk samples/s | disk faster by |")
    print("|---|---|---|---|---|---|")
    for size in args.sizes:
        samples = ns.Samples(size=size, seed=0)
        n = min(args.samples, len(samples))
        with tempfile.TemporaryDirectory() as d:
            d = Path(d)
            # The shards, in neuspike dataset's layout (the same arrays it writes: tested).
            for k, start in enumerate(range(0, n, args.shard)):
                b = samples.batch(list(range(start, min(start + args.shard, n))))
                (d / f"{k:03}").mkdir()
                for a in ARRAYS:
                    np.save(d / f"{k:03}" / f"{a}.npy", b[a])
            shards = sorted(p for p in d.iterdir() if p.is_dir())

            def from_disk():
                return {a: np.concatenate([np.load(s / f"{a}.npy") for s in shards]) for a in ARRAYS}

            from_disk()  # warm the page cache
            _, t_disk = timed(from_disk)
            for threads in sorted({1, cores}):
                ns.set_threads(threads)
                _, t_batch = timed(lambda: [samples.batch(list(range(i, min(i + 32, n)))) for i in range(0, n, 32)])
                m = max(1, n // 4)
                _, t_one = timed(lambda: [samples[i] for i in range(m)])
                print(
                    f"| {size}x{size} | {threads} | {rate(n, t_batch):.0f} | {rate(m, t_one):.0f} | "
                    f"{rate(n, t_disk):.0f} | {t_batch / t_disk:.0f}x |"
                )
    ns.set_threads(0)


if __name__ == "__main__":
    main()
