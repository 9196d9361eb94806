"""A node of one's own, in Python: a TFP representation in, a frame out, tone-mapped with a gamma
curve, ``frame = clamp(tfp, 0, 1) ** gamma`` (the same method as the Rust example node, so the two
can be checked against each other). Replace :func:`tone_map` with your own method; ``run`` stays
the same.

    python node.py --gamma 0.5     # started by dora from a graph (examples/python-node/graph.yml)

It needs pyarrow, numpy and dora-rs (``pip install dora-rs==1.1.0 pyarrow numpy``), and
neuspike's Python package: ``pip install ./python`` from the repository, or nothing when it runs
from the repository (the path is found from this file).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

try:
    import neuspike
except ImportError:  # running from the repository
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "python"))
    import neuspike

from neuspike import Frame, Link, Representation


def tone_map(rep: Representation, gamma: float) -> Frame:
    """The frame of a one-channel representation: each value clamped to [0, 1] (NaN counts as
    0), raised to ``gamma``; the window's instant and sequence number are kept, so that the sink
    pairs it with its ground truth and counts it."""
    start = time.perf_counter_ns()
    c, h, w = rep.data.shape
    if c != 1:
        raise ValueError(f"representation {rep.kind} (seq {rep.seq}): {c} channels, this node takes one (tfp)")
    v = np.nan_to_num(rep.data[0], nan=0.0).clip(0.0, 1.0)
    data = np.power(v, np.float32(gamma), dtype=np.float32)
    return Frame(
        kind="reconstruction",
        method="gamma-py",
        t_ref_ns=rep.t_ref_ns,
        compute_ns=time.perf_counter_ns() - start,
        seq=rep.seq,
        data=data,
    )


def run(link: Link, gamma: float) -> None:
    """Sends the frame of every representation, in order, then the end-of-stream marker."""
    link.declare("frames", Frame)
    for _input, meta, data in link.messages():
        link.send("frames", tone_map(Representation.from_arrow(meta, data), gamma))
    # A window lost upstream is announced downstream too.
    link.at_least("frames", link.announced())
    link.end_all()


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="gamma-py", description="Tone-maps TFP representations")
    p.add_argument("--gamma", type=float, default=0.5, help="the exponent, in (0, 10]")
    a = p.parse_args(argv)
    if not 0.0 < a.gamma <= 10.0:
        p.error(f"--gamma {a.gamma}: must be in (0, 10]")
    return a


def main() -> int:
    args = parse_args()
    node = neuspike.link.init_node()
    try:
        run(Link(node), args.gamma)
    except (neuspike.SchemaError, ValueError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
