"""neuspike's Python messages: round trips, errors, IPC bytes, and, when the Rust side wrote its
messages into ``$NEUSPIKE_RUST_MESSAGES`` (tests/python.rs does), the same values and the very
same error texts as the Rust schemas. With ``$NEUSPIKE_PYTHON_OUT`` set, the messages this
package writes are left there for the Rust side to read.

    python3 -m unittest discover -s python/tests
"""

import os
import random
import sys
import unittest
from pathlib import Path

import numpy as np
import pyarrow as pa

# The package installed (or on PYTHONPATH) first, else the sources beside these tests.
sys.path.append(str(Path(__file__).resolve().parents[1]))

from neuspike import (  # noqa: E402
    Credit,
    EventBatch,
    Frame,
    IpcError,
    Representation,
    SchemaError,
    SpikeChunk,
    decode,
    encode,
    end_of_stream,
    is_end_of_stream,
)
from neuspike.messages import MESSAGES, rust_f32, rust_float  # noqa: E402


# The values tests/python.rs builds on the Rust side.
def frame():
    y, x = np.mgrid[0:2, 0:3]
    return Frame("reconstruction", "tfp", -5, 7, 3, ((y * 3 + x) / 8.0).astype(np.float32))


def representation():
    c, y, x = np.mgrid[0:2, 0:3, 0:4]
    return Representation(
        "isi", 42, 1, (c * 100 + y * 10 + x).astype(np.float32), {"tau_ns": 0.25, "window": 33.0}
    )


def spike_chunk():
    return SpikeChunk(9, 2, 40, 2, 2_000_000, 50_000, 2, bytes([0xA5, 0x01, 0x80, 0x00, 0xFF, 0x02]), 20.0)


def event_batch():
    return EventBatch(
        346,
        260,
        1_000,
        2_000,
        4,
        np.array([1_000, 1_500, 1_500, 1_999], np.int64),
        np.array([0, 345, 7, 100], np.uint16),
        np.array([0, 259, 8, 200], np.uint16),
        np.array([1, -1, -1, 1], np.int8),
    )


def credit():
    return Credit(True, [("align/windows", 8), ("represent/tfp", 3)])


def same(a, b):
    """Message equality, arrays compared by value."""
    if type(a) is not type(b):
        return False
    for k, v in vars(a).items():
        w = vars(b)[k]
        if isinstance(v, np.ndarray) or isinstance(w, np.ndarray):
            if not np.array_equal(np.asarray(v), np.asarray(w)):
                return False
        elif v != w:
            return False
    return True


GOOD = {
    "frame": frame,
    "representation": representation,
    "spike_chunk": spike_chunk,
    "event_batch": event_batch,
    "credit": credit,
}


class RoundTrips(unittest.TestCase):
    def test_every_message_comes_back_whole(self):
        for name, make in GOOD.items():
            msg = make()
            meta, data = msg.to_arrow()
            self.assertTrue(same(type(msg).from_arrow(meta, data), msg), name)
            urn, m, d = decode(encode(type(msg).TYPE_URN, meta, data))
            self.assertEqual(urn, type(msg).TYPE_URN)
            self.assertEqual(m, meta, name)
            self.assertTrue(same(MESSAGES[urn].from_arrow(m, d), msg), name)

    def test_spike_planes_pack_as_the_rust_side_packs_them(self):
        rng = np.random.default_rng(1)
        planes = (rng.random((3, 5, 7)) < 0.3).astype(np.uint8)
        chunk = SpikeChunk.from_planes(
            planes, first_plane=0, t_first_ns=0, plane_period_ns=25_000, seq=0
        )
        self.assertEqual(len(chunk.bits), 3 * 5)  # 35 pixels: 5 bytes a plane
        self.assertTrue(np.array_equal(chunk.planes(), planes))
        # Pixel k = y * width + x at bit k & 7 of byte k >> 3, least significant first.
        one = np.zeros((1, 2, 9), np.uint8)
        one[0, 1, 0] = 1  # k = 9: byte 1, bit 1
        self.assertEqual(
            SpikeChunk.from_planes(one, first_plane=0, t_first_ns=0, plane_period_ns=1, seq=0).bits,
            bytes([0, 2, 0]),
        )

    def test_end_of_stream_markers(self):
        meta, data = end_of_stream(Frame, 12)
        self.assertEqual(is_end_of_stream(meta), 12)
        self.assertEqual(len(data), 0)
        self.assertEqual(data.type, pa.float32())
        self.assertIsNone(is_end_of_stream(frame().to_arrow()[0]))

    def test_floats_read_as_rust_writes_them(self):
        self.assertEqual(rust_float(0.5), "0.5")
        self.assertEqual(rust_float(1.0), "1")
        self.assertEqual(rust_float(-1.5), "-1.5")
        self.assertEqual(rust_float(1e20), "100000000000000000000")
        self.assertEqual(rust_float(1e-7), "0.0000001")
        self.assertEqual(rust_float(float("nan")), "NaN")
        self.assertEqual(rust_f32(np.float32(0.1)), "0.1")
        self.assertEqual(rust_f32(np.float32("-inf")), "-inf")


class Errors(unittest.TestCase):
    def test_errors_name_the_key_and_the_value(self):
        meta, data = frame().to_arrow()
        del meta["width"]
        with self.assertRaises(SchemaError) as e:
            Frame.from_arrow(meta, data)
        self.assertEqual(str(e.exception), "frame: metadata key `width` is missing")
        meta, _ = frame().to_arrow()
        bad = pa.array([0, 0.1, 0.2, 0.3, float("nan"), 0.5], pa.float32())
        with self.assertRaises(SchemaError) as e:
            Frame.from_arrow(meta, bad)
        self.assertIn("value 4 is NaN", str(e.exception))
        b = event_batch()
        b.y[3] = 260
        meta, data = b.to_arrow()
        with self.assertRaises(SchemaError) as e:
            EventBatch.from_arrow(meta, data)
        self.assertEqual(
            str(e.exception), "event batch: event 3 at (100, 260) is outside the 346x260 sensor"
        )

    def test_damaged_bytes_are_an_ipc_error_never_another_exception(self):
        meta, data = frame().to_arrow()
        good = encode(Frame.TYPE_URN, meta, data)
        for cut in (0, 1, 8, len(good) // 2, len(good) - 1):
            try:
                decode(good[:cut])
            except IpcError:
                pass
        rng = random.Random(7)
        for _ in range(500):
            b = bytearray(good)
            for _ in range(4):
                b[rng.randrange(len(b))] = rng.randrange(256)
            try:
                urn, m, d = decode(bytes(b))
                MESSAGES.get(urn, Frame).from_arrow(m, d)
            except (IpcError, SchemaError):
                pass
        with self.assertRaises(IpcError):
            decode(b"not arrow at all")


RUST = os.environ.get("NEUSPIKE_RUST_MESSAGES")
OUT = os.environ.get("NEUSPIKE_PYTHON_OUT")


@unittest.skipUnless(RUST, "NEUSPIKE_RUST_MESSAGES is not set (tests/python.rs sets it)")
class WhatRustWrote(unittest.TestCase):
    def read(self, name):
        return decode((Path(RUST) / f"{name}.arrow").read_bytes())

    def test_the_same_values(self):
        for name, make in GOOD.items():
            urn, meta, data = self.read(name)
            msg = MESSAGES[urn].from_arrow(meta, data)
            self.assertTrue(same(msg, make()), f"{name}: {msg} != {make()}")
        urn, meta, data = self.read("end_of_stream")
        self.assertEqual(urn, Frame.TYPE_URN)
        self.assertEqual(is_end_of_stream(meta), 17)
        self.assertEqual(len(data), 0)

    def test_the_same_errors(self):
        cases = sorted(Path(RUST).glob("bad-*.arrow"))
        self.assertEqual(len(cases), 20)
        for path in cases:
            expected = path.with_suffix(".txt").read_text()
            urn, meta, data = decode(path.read_bytes())
            with self.assertRaises(SchemaError, msg=path.name) as e:
                MESSAGES[urn].from_arrow(meta, data)
            self.assertEqual(str(e.exception), expected, path.name)


@unittest.skipUnless(OUT, "NEUSPIKE_PYTHON_OUT is not set (tests/python.rs sets it)")
class ForRustToRead(unittest.TestCase):
    def test_write(self):
        for name, make in GOOD.items():
            msg = make()
            meta, data = msg.to_arrow()
            (Path(OUT) / f"{name}.arrow").write_bytes(encode(type(msg).TYPE_URN, meta, data))
        meta, data = end_of_stream(Frame, 17, cut=True)
        (Path(OUT) / "end_of_stream.arrow").write_bytes(encode(Frame.TYPE_URN, meta, data))


if __name__ == "__main__":
    unittest.main()
