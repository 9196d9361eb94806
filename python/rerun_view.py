"""Shows a graph's frames (and events) live in rerun, the viewer of the dora ecosystem, added to a
graph by one node entry:

    - id: view
      path: ../python/rerun_view.py        # relative to the graph's folder
      args: --spawn                         # or --connect URL, or --save run.rrd
      inputs:
        tfp: { source: infer-tfp/frames, queue_size: 2 }

Every Frame input is logged as an image under ``frames/<input>`` (8-bit grey, as the sink's PNGs:
``round(clamp(v, 0, 1) * 255)``), every EventBatch input as points under ``events/<input>``
(ON green, OFF red), on the timelines ``t_ref`` (the camera's clock) and ``seq``. The node returns
no credits, so its producers never wait for it: a viewer that falls behind drops frames (dora's
queue keeps the newest ``queue_size``) and never slows the graph; what it missed is counted in
its log.

Needs ``pip install rerun-sdk dora-rs==1.1.0 pyarrow numpy``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa

try:
    import neuspike
except ImportError:  # running from the repository
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import neuspike

from neuspike import EventBatch, Frame, Link
from neuspike.messages import SchemaError


def grey8(frame: Frame) -> np.ndarray:
    """The frame as the sink writes its 8-bit PNGs (NaN never travels; clamp, then round)."""
    return np.rint(np.clip(frame.data, 0.0, 1.0) * 255.0).astype(np.uint8)


def run(link: Link, rr) -> dict:
    """Logs every message of the node's inputs until they end; returns how many per input."""
    shown = {}
    for input_id, meta, data in link.messages():
        try:
            is_frame = pa.types.is_float32(data.type)
            msg = Frame.from_arrow(meta, data) if is_frame else EventBatch.from_arrow(meta, data)
        except SchemaError as e:
            raise SchemaError(f"input `{input_id}`: {e}") from None
        if isinstance(msg, Frame):
            rr.set_time("t_ref", duration=np.timedelta64(msg.t_ref_ns, "ns"))
            rr.set_time("seq", sequence=msg.seq)
            rr.log(f"frames/{input_id}", rr.Image(grey8(msg)))
        else:
            rr.set_time("t_ref", duration=np.timedelta64(msg.t_start_ns, "ns"))
            rr.set_time("seq", sequence=msg.seq)
            colors = np.where(np.asarray(msg.polarity)[:, None] > 0, [[0, 200, 0]], [[220, 0, 0]])
            xy = np.stack([np.asarray(msg.x, np.float32), np.asarray(msg.y, np.float32)], axis=1)
            rr.log(f"events/{input_id}", rr.Points2D(xy, colors=colors.astype(np.uint8), radii=0.5))
        shown[input_id] = shown.get(input_id, 0) + 1
    return shown


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="rerun_view", description="Shows a graph's frames in rerun")
    # Not exclusive, so that a graph's `--set view="--save x.rrd"` overrides its `--spawn`:
    # --save wins over --connect, which wins over --spawn.
    p.add_argument("--spawn", action="store_true", help="start a viewer on this machine (default)")
    p.add_argument("--connect", metavar="URL", help="send to a running viewer, e.g. rerun+http://host:9876/proxy")
    p.add_argument("--save", metavar="FILE", help="write a recording (.rrd) instead")
    p.add_argument("--name", default="neuspike", help="the recording's application id")
    return p.parse_args(argv)


def open_rerun(args: argparse.Namespace):
    import rerun as rr

    rr.init(args.name, spawn=False)
    if args.save:
        rr.save(args.save)
    elif args.connect:
        rr.connect_grpc(args.connect)
    else:
        rr.spawn()
    return rr


def main() -> int:
    args = parse_args()
    node = neuspike.link.init_node()
    try:
        rr = open_rerun(args)
        shown = run(Link(node), rr)
        rr.disconnect()
    except (SchemaError, ValueError, RuntimeError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"rerun_view: shown {shown}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
