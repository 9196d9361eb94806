"""The rerun viewer node (python/rerun_view.py) driven with canned events and no daemon: its
recording, read back by rerun's own tool, holds every frame and every event batch.

    python3 -m unittest discover -s python/tests
"""

import subprocess
import sys
import tempfile
import unittest
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
# The package installed (or on PYTHONPATH) first, else the sources beside these tests.
sys.path.append(str(HERE))

from neuspike import EventBatch, Frame, Link, end_of_stream  # noqa: E402

try:
    import rerun  # noqa: F401

    HAVE_RERUN = True
except ImportError:
    HAVE_RERUN = False


def event(input_id, message):
    meta, data = message if isinstance(message, tuple) else message.to_arrow()
    return {"type": "INPUT", "id": input_id, "value": data, "metadata": dict(meta)}


class NoSends:
    def send_output(self, *a):
        raise AssertionError("a viewer sends nothing")


@unittest.skipUnless(HAVE_RERUN, "rerun-sdk is not installed (pip install rerun-sdk)")
class RerunView(unittest.TestCase):
    def test_every_frame_and_batch_is_in_the_recording(self):
        import rerun_view

        frames = [
            Frame("reconstruction", "tfp", 1_000 * i, 5, i, np.full((25, 40), i / 3, np.float32))
            for i in range(3)
        ]
        batch = EventBatch(
            40, 25, 0, 100, 0,
            np.array([1, 2], np.int64), np.array([3, 4], np.uint16),
            np.array([5, 6], np.uint16), np.array([1, -1], np.int8),
        )
        events = [event("tfp", f) for f in frames] + [
            event("events", batch),
            event("tfp", end_of_stream(Frame, 3)),
            event("events", end_of_stream(EventBatch, 1)),
        ]
        self.assertEqual(rerun_view.grey8(frames[1]).max(), 85, "round(1/3 * 255)")
        with tempfile.TemporaryDirectory() as d:
            rrd = Path(d) / "run.rrd"
            rr = rerun_view.open_rerun(rerun_view.parse_args(["--save", str(rrd)]))
            config = {"inputs": {"tfp": "infer/frames", "events": "align/events"}, "outputs": []}
            shown = rerun_view.run(Link(NoSends(), events, node_id="view", config=config), rr)
            rr.disconnect()
            self.assertEqual(shown, {"tfp": 3, "events": 1})
            out = subprocess.run(
                [sys.executable, "-m", "rerun", "rrd", "print", str(rrd)],
                capture_output=True, text=True, timeout=120, check=True,
            ).stdout
        rows = {}
        for line in set(out.splitlines()):
            if line.startswith("Chunk(") and " rows " in line:
                entity = line.split(" - ")[1].strip()
                rows[entity] = rows.get(entity, 0) + int(line.split(" with ")[1].split(" rows")[0])
        self.assertEqual(rows.get("/frames/tfp"), 3, out)
        self.assertEqual(rows.get("/events/events"), 1, out)


if __name__ == "__main__":
    unittest.main()
