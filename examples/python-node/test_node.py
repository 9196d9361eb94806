"""The example Python node driven with canned events and a stand-in for dora's node: no daemon.

    python3 -m unittest examples/python-node/test_node.py
"""

import sys
import unittest
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "python"))

import node  # noqa: E402
from neuspike import Credit, Frame, Link, Representation, end_of_stream, is_end_of_stream  # noqa: E402

CONFIG = {
    "inputs": {
        "representation": {"source": "represent/tfp", "queue_size": 2},
        "credits-sink": {"source": "sink/credits", "queue_size": 100},
    },
    "outputs": ["frames", "credits"],
}


class Recorder:
    """Stands in for dora's node: keeps what the node sends."""

    def __init__(self):
        self.sent = []

    def send_output(self, output, data, metadata=None):
        self.sent.append((output, data, dict(metadata or {})))


def event(input_id, message):
    meta, data = message if isinstance(message, tuple) else message.to_arrow()
    return {"type": "INPUT", "id": input_id, "value": data, "metadata": dict(meta)}


def rep(seq, value):
    return Representation("tfp", 1_000 * seq, seq, np.full((1, 2, 3), value, np.float32))


class Node(unittest.TestCase):
    def test_every_representation_becomes_a_frame_in_order_and_the_stream_ends(self):
        events = [
            event("credits-sink", Credit(True, [("gamma/frames", 2), ("other/out", 5)])),
            event("representation", rep(0, 0.25)),
            event("representation", rep(1, 4.0)),
            event("credits-sink", Credit(False, [("gamma/frames", 2)])),
            # seq 2 never came: a counted gap.
            event("representation", rep(3, -2.0)),
            event("representation", end_of_stream(Representation, 5)),
            event("credits-sink", Credit(False, [("gamma/frames", 2)])),
            {"type": "STOP", "id": "MANUAL", "metadata": {}},
        ]
        dora = Recorder()
        link = Link(dora, events, node_id="gamma", config=CONFIG)
        node.run(link, gamma=0.5)

        credits = [Credit.from_arrow(m, d) for o, d, m in dora.sent if o == "credits"]
        self.assertEqual(credits[0], Credit(True, [("represent/tfp", 2)]), "the hello")
        # A window of 2 returns one credit a message; the gap's credit comes back too.
        self.assertEqual(sum(n for c in credits[1:] for _, n in c.grants), 4)

        frames = [(d, m) for o, d, m in dora.sent if o == "frames"]
        self.assertEqual(len(frames), 4, "three frames and the end-of-stream marker")
        got = [Frame.from_arrow(m, d) for d, m in frames[:3]]
        self.assertEqual([f.seq for f in got], [0, 1, 3])
        self.assertTrue(np.allclose(got[0].data, 0.5), "0.25 ** 0.5")
        self.assertTrue(np.all(got[1].data == 1.0), "clamped to 1")
        self.assertTrue(np.all(got[2].data == 0.0), "clamped to 0")
        self.assertEqual([m["link_n"] for _, m in frames], [0, 1, 2, 3])
        self.assertEqual(is_end_of_stream(frames[3][1]), 5, "the loss announced downstream")
        self.assertEqual(link.missing(), 2, "seq 2 and seq 4")

    def test_a_frame_waits_for_the_consumers_credit(self):
        # The sink grants one frame; the second waits until its credit comes, while the
        # representation that arrives meanwhile is kept for later, in order.
        events = [
            event("credits-sink", Credit(True, [("gamma/frames", 1)])),
            event("representation", rep(0, 0.25)),
            event("representation", rep(1, 0.25)),
            event("representation", end_of_stream(Representation, 2)),
            event("credits-sink", Credit(False, [("gamma/frames", 1)])),
            event("credits-sink", Credit(False, [("gamma/frames", 1)])),
            event("credits-sink", Credit(False, [("gamma/frames", 1)])),
        ]
        dora = Recorder()
        node.run(Link(dora, events, node_id="gamma", config=CONFIG), gamma=1.0)
        order = [(o, m.get("seq"), m.get("eos")) for o, _, m in dora.sent if o == "frames"]
        self.assertEqual(order, [("frames", 0, None), ("frames", 1, None), ("frames", None, True)])

    def test_a_producer_that_died_cuts_the_stream(self):
        events = [
            event("credits-sink", Credit(True, [("gamma/frames", 4)])),
            event("representation", rep(0, 0.25)),
            {"type": "INPUT_CLOSED", "id": "representation"},
            event("credits-sink", Credit(False, [("gamma/frames", 4)])),
        ]
        dora = Recorder()
        node.run(Link(dora, events, node_id="gamma", config=CONFIG), gamma=1.0)
        _, _, last = dora.sent[-1]
        self.assertEqual(last.get("eos"), True)
        self.assertEqual(last.get("cut"), True, "the marker says the stream was cut short")

    def test_a_bad_message_is_a_one_line_error(self):
        meta, data = rep(0, 0.5).to_arrow()
        meta["kind"] = "tfp2"
        events = [event("credits-sink", Credit(True, [("gamma/frames", 4)])), event("representation", (meta, data))]
        with self.assertRaises(ValueError) as e:
            node.run(Link(Recorder(), events, node_id="gamma", config=CONFIG), gamma=1.0)
        self.assertIn("metadata key `kind` is \"tfp2\"", str(e.exception))
        self.assertNotIn("\n", str(e.exception))

    def test_settings_are_checked(self):
        self.assertEqual(node.parse_args(["--gamma", "2"]).gamma, 2.0)
        with self.assertRaises(SystemExit):
            node.parse_args(["--gamma", "0"])


if __name__ == "__main__":
    unittest.main()
