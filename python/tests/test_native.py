"""neuspike's library from Python (the native module): every kernel against a plain numpy
reference, packed spikes against unpacked, files written and read back, the simulator's
determinism, the errors' kinds and texts, arrays handed over without copies, and the thread pool
in forked and spawned workers.

    pip install ./python && python3 -m pytest python/tests

Skips with a notice where the package was not built (the sources alone have no native module),
unless ``$NEUSPIKE_REQUIRE_NATIVE`` is set (tests/python.rs sets it).
"""

import importlib.util
import multiprocessing
import os
import tempfile
import threading
import unittest
from pathlib import Path

import numpy as np

import neuspike as ns

REQUIRED = bool(os.environ.get("NEUSPIKE_REQUIRE_NATIVE"))
if not ns.NATIVE:
    if REQUIRED:
        raise ImportError("neuspike's native module is required here but was not found")
    print("notice: neuspike's native module is not built (pip install ./python); skipping")


def random_planes(n, h, w, p=0.3, seed=0):
    return (np.random.default_rng(seed).random((n, h, w)) < p).astype(np.uint8)


def isi_reference(planes, c):
    """docs/definitions.md's ISI at plane c, pixel by pixel, with its bounds."""
    n, h, w = planes.shape
    isi = np.zeros((h, w), np.float32)
    valid = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            col = planes[:, y, x]
            before = [k for k in range(c + 1) if col[k]]
            after = [k for k in range(c + 1, n) if col[k]]
            prev = before[-1] + 1 if before else 0
            nxt = after[0] if after else n
            valid[y, x] = bool(before) and bool(after)
            isi[y, x] = nxt - prev + 1
    return isi, valid


def random_events(n, h, w, seed=0, t_span=1_000_000):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, t_span, n)).astype(np.int64)
    x = rng.integers(0, w, n).astype(np.uint16)
    y = rng.integers(0, h, n).astype(np.uint16)
    p = rng.choice(np.array([-1, 1], np.int8), n)
    return ns.Events(t, x, y, p, w, h)


def truth_in_worker(args):
    """A spawned or forked worker's sample, from a pickled set."""
    samples, i = args
    return samples[i]["truth"]


def tfp_in_worker(seed):
    """A DataLoader worker's work: simulate and represent."""
    sim = ns.simulate("bright-slow", 40, seed=seed, events=False, truth_every=0)
    return ns.tfp(sim.spikes)


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class SpikesTest(unittest.TestCase):
    def test_packing_is_numpys_little_endian_bit_order(self):
        planes = random_planes(5, 7, 9)
        s = ns.Spikes.from_planes(planes, t_first_ns=100, plane_period_ns=25)
        bits = np.packbits(planes.reshape(5, -1), axis=1, bitorder="little")
        np.testing.assert_array_equal(s.packed, bits)
        np.testing.assert_array_equal(s.unpack(), planes)
        self.assertEqual((len(s), s.width, s.height), (5, 9, 7))
        np.testing.assert_array_equal(s.plane_times_ns(), 100 + 25 * np.arange(5))
        same = ns.Spikes(bits, 9, 7)
        np.testing.assert_array_equal(same.unpack(), planes)
        self.assertTrue(np.shares_memory(same.packed, bits))

    def test_bool_planes_are_spikes_too(self):
        planes = random_planes(4, 3, 5)
        np.testing.assert_array_equal(
            ns.Spikes.from_planes(planes.astype(bool)).packed,
            ns.Spikes.from_planes(planes).packed,
        )

    def test_a_window_shares_the_planes_and_moves_the_clock(self):
        s = ns.Spikes.from_planes(random_planes(10, 4, 4), t_first_ns=0, plane_period_ns=50)
        w = s.window(3, 7)
        self.assertEqual((len(w), w.first_plane, w.t_first_ns), (4, 3, 150))
        self.assertTrue(np.shares_memory(w.packed, s.packed))
        np.testing.assert_array_equal(w.unpack(), s.unpack()[3:7])
        self.assertEqual(len(s.window(-2, 100)), 2)

    def test_sizes_and_clocks_past_their_integers_are_refused(self):
        with self.assertRaisesRegex(ns.InputError, "each side must be 1..=65535"):
            ns.Spikes(np.zeros((1, 0), np.uint8), 2**32, 2**32)
        with self.assertRaisesRegex(ns.InputError, "run past a 64-bit clock"):
            ns.Spikes(np.zeros((3, 2), np.uint8), 4, 4, t_first_ns=2**63 - 10)
        with self.assertRaisesRegex(ns.InputError, "run past a 64-bit clock"):
            ns.Spikes.from_planes(random_planes(3, 2, 2), plane_period_ns=2**62)
        with self.assertRaisesRegex(ns.InputError, "a sensor of 1000000x1000000"):
            ns.Events([0], [0], [0], [1], 10**6, 10**6)
        with self.assertRaisesRegex(ns.InputError, "more than the 1073741824 values"):
            ns.voxel_grid(random_events(10, 4, 4), 10**9)
        with self.assertRaisesRegex(ns.InputError, "x: value -1 at index 1 is not a uint16"):
            ns.Events([0, 1], [0, -1], [0, 0], [1, 1], 4, 4)
        with self.assertRaisesRegex(ns.InputError, "t_ns: value 0.5 at index 0 is not a int64"):
            ns.Events([0.5], [0], [0], [1], 4, 4)

    def test_bad_packed_shapes_are_named(self):
        with self.assertRaisesRegex(ns.InputError, r"expected shape \[N, 4\] for 5x6 planes"):
            ns.Spikes(np.zeros((2, 3), np.uint8), 5, 6)
        with self.assertRaisesRegex(ns.InputError, "plane_period_ns = 0"):
            ns.Spikes.from_planes(random_planes(1, 2, 2), plane_period_ns=0)
        with self.assertRaisesRegex(ns.InputError, "uint8 or bool, got an array of float64"):
            ns.tfp(np.zeros((2, 2, 2)))


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class SpikeRepresentationsTest(unittest.TestCase):
    def setUp(self):
        self.planes = random_planes(33, 11, 13, p=0.2, seed=3)
        self.packed = ns.Spikes.from_planes(self.planes)

    def test_tfp_is_the_mean_rate(self):
        for s in (self.planes, self.packed):
            np.testing.assert_allclose(ns.tfp(s), self.planes.mean(axis=0), rtol=0, atol=1e-7)

    def test_isi_and_tfi_match_the_definition(self):
        for c in (0, 7, 16, 32):
            isi_ref, valid_ref = isi_reference(self.planes, c)
            for s in (self.planes, self.packed):
                isi, valid = ns.isi(s, c)
                np.testing.assert_array_equal(isi, isi_ref)
                np.testing.assert_array_equal(valid, valid_ref)
                np.testing.assert_array_equal(ns.tfi(s, c), (1 / isi_ref).astype(np.float32))
        np.testing.assert_array_equal(ns.tfi(self.planes), ns.tfi(self.planes, 16))

    def test_the_spike_representation_is_tfi_then_planes(self):
        for s in (self.planes, self.packed):
            r = ns.spike_representation(s, 16, 5)
            self.assertEqual(r.shape, (5, 11, 13))
            np.testing.assert_array_equal(r[0], ns.tfi(self.planes, 16))
            np.testing.assert_array_equal(r[1:], self.planes[14:18].astype(np.float32))

    def test_tfstp_is_the_same_packed_or_not(self):
        a, b = ns.tfstp(self.planes), ns.tfstp(self.packed)
        np.testing.assert_array_equal(a, b)
        self.assertGreater(float(a.max()), 0.0)
        with self.assertRaisesRegex(ns.InputError, "u0"):
            ns.tfstp(self.planes, u0=2.0)

    def test_a_reference_outside_the_window_is_named(self):
        with self.assertRaisesRegex(ns.InputError, "33"):
            ns.tfi(self.packed, 33)


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class EventRepresentationsTest(unittest.TestCase):
    def setUp(self):
        self.ev = random_events(5000, 9, 12, seed=1)
        self.cols = [np.asarray(c).astype(np.int64) for c in (self.ev.t_ns, self.ev.x, self.ev.y, self.ev.polarity)]

    def test_columns_go_in_and_out_without_copies(self):
        t, x, y, p = (np.asarray(c) for c in (self.ev.t_ns, self.ev.x, self.ev.y, self.ev.polarity))
        again = ns.Events(t, x, y, p, 12, 9)
        for a, b in ((again.t_ns, t), (again.x, x), (again.y, y), (again.polarity, p)):
            self.assertTrue(np.shares_memory(a, b))
        s = again.to_structured()
        back = ns.Events.from_structured(s, 12, 9)
        np.testing.assert_array_equal(back.t_ns, t)
        np.testing.assert_array_equal(back.polarity, p)
        self.assertEqual((len(back), back.t_start_ns, back.t_end_ns), (5000, int(t[0]), int(t[-1]) + 1))

    def test_event_count(self):
        t, x, y, p = self.cols
        ref = np.zeros((9, 12), np.float32)
        np.add.at(ref, (y, x), p)
        np.testing.assert_array_equal(ns.event_count(self.ev), ref)

    def test_voxel_grid_is_e2vids(self):
        t, x, y, p = self.cols
        bins = 5
        ts = (bins - 1) * (t - t[0]) / (t[-1] - t[0])
        ref = np.zeros((bins, 9, 12), np.float64)
        for b in range(bins):
            np.add.at(ref[b], (y, x), p * np.maximum(0, 1 - np.abs(b - ts)))
        np.testing.assert_allclose(ns.voxel_grid(self.ev, bins), ref, atol=1e-4)
        v = ns.voxel_grid(self.ev, bins, normalise=True)
        nz = v[v != 0]
        self.assertAlmostEqual(float(nz.mean()), 0.0, places=4)
        self.assertAlmostEqual(float(nz.std()), 1.0, places=3)

    def test_event_stack_keeps_every_event(self):
        s = ns.event_stack(self.ev, 4)
        self.assertEqual(s.shape, (4, 9, 12))
        self.assertEqual(float(s.sum()), float(self.cols[3].sum()))

    def test_time_surface_decays_from_the_latest_event(self):
        t_ref = 1_000_000
        s = ns.time_surface(self.ev, t_ref, 100_000.0)
        t, x, y, p = self.cols
        on = (p == 1) & (y == 0) & (x == 0)
        expected = np.exp(-(t_ref - t[on][-1]) / 100_000.0) if on.any() else 0.0
        self.assertAlmostEqual(float(s[0, 0, 0]), float(expected), places=5)

    def test_event_integration_weighs_by_the_decay(self):
        ev = ns.Events(np.array([1_000]), np.array([0]), np.array([0]), np.array([1]), 1, 1)
        v = ns.event_integration(ev, 0, [500, 1_500], 500.0)
        self.assertEqual(float(v[0, 0, 0]), 0.0)
        self.assertAlmostEqual(float(v[1, 0, 0]), 1 + np.exp(-1), places=6)

    def test_bad_events_are_named(self):
        with self.assertRaisesRegex(ns.InputError, "x has 1 values, t_ns has 2"):
            ns.Events([0, 1], [0], [0, 0], [1, 1], 4, 4)
        unsorted = ns.Events([5, 1], [0, 0], [0, 0], [1, 1], 4, 4)
        with self.assertRaisesRegex(ns.InputError, "t_ns"):
            ns.event_count(unsorted)
        outside = ns.Events([0], [4], [0], [1], 4, 4)
        with self.assertRaisesRegex(ns.InputError, "x of event 0 = 4 is out of range"):
            ns.voxel_grid(outside, 2)


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class FilesTest(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.path = Path(self.dir.name)

    def tearDown(self):
        self.dir.cleanup()

    def test_spike_files_round_trip_whole_and_streamed(self):
        planes = random_planes(25, 6, 10, seed=4)
        f = self.path / "s.dat"
        self.assertEqual(ns.write_spikes(f, planes), 25)
        self.assertEqual(f.stat().st_size, 25 * 8)  # ceil(60 / 8) bytes a plane
        s = ns.read_spikes(f, width=10, height=6, plane_period_ns=1000)
        np.testing.assert_array_equal(s.unpack(), planes)
        self.assertEqual(s.plane_period_ns, 1000)
        self.assertEqual(len(ns.read_spikes(f, width=10, height=6, max_planes=4)), 4)
        chunks = list(ns.SpikeReader(f, chunk_planes=10, width=10, height=6))
        self.assertEqual([len(c) for c in chunks], [10, 10, 5])
        self.assertEqual([c.first_plane for c in chunks], [0, 10, 20])
        np.testing.assert_array_equal(np.concatenate([c.unpack() for c in chunks]), planes)

    def test_a_damaged_tail_comes_after_every_whole_plane(self):
        planes = random_planes(4, 8, 8, seed=5)
        f = self.path / "cut.dat"
        ns.write_spikes(f, planes)
        with open(f, "ab") as out:
            out.write(b"\x01\x02\x03")
        reader = ns.SpikeReader(f, chunk_planes=3, width=8, height=8)
        got = [next(reader), next(reader)]
        np.testing.assert_array_equal(np.concatenate([c.unpack() for c in got]), planes)
        with self.assertRaises(ns.FormatError) as e:
            next(reader)
        self.assertIn("cut.dat", str(e.exception))
        with self.assertRaisesRegex(ns.FormatError, "cut.dat"):
            ns.read_spikes(f, width=8, height=8)

    def test_event_files_round_trip_in_every_format(self):
        rng = np.random.default_rng(6)
        n = 3000
        t = np.sort(rng.integers(0, 10_000, n)) * 1000  # whole microseconds
        ev = ns.Events(t, rng.integers(0, 40, n), rng.integers(0, 30, n), rng.choice([-1, 1], n), 40, 30)
        for name, fmt in (("e.txt", None), ("e.raw", None), ("e2.raw", "evt2"), ("e.dat", None), ("e.aedat4", None)):
            f = self.path / name
            self.assertEqual(ns.write_events(f, ev, format=fmt), n, name)
            back = ns.read_events(f, width=40, height=30) if name.endswith("dat") else ns.read_events(f)
            self.assertEqual((back.width, back.height), (40, 30), name)
            for a, b in ((back.t_ns, ev.t_ns), (back.x, ev.x), (back.y, ev.y), (back.polarity, ev.polarity)):
                np.testing.assert_array_equal(a, b, err_msg=name)
            chunks = list(ns.EventReader(f, chunk_events=1000, width=40, height=30) if name.endswith("dat") else ns.EventReader(f, chunk_events=1000))
            self.assertEqual(sum(len(c) for c in chunks), n, name)
            self.assertEqual(len(ns.read_events(f, width=40, height=30, max_events=7) if name.endswith("dat") else ns.read_events(f, max_events=7)), 7)

    def test_file_errors_name_the_file(self):
        with self.assertRaisesRegex(ns.FormatError, "missing.dat"):
            ns.read_spikes(self.path / "missing.dat")
        with self.assertRaisesRegex(ns.ConfigError, r'format "xyz"'):
            ns.write_events(self.path / "e.xyz", random_events(3, 2, 2))
        junk = self.path / "junk.txt"
        junk.write_text("4 4\n0.000001 9 0 1\n")
        with self.assertRaisesRegex(ns.FormatError, "junk.txt"):
            ns.read_events(junk)
        with self.assertRaisesRegex(ns.ConfigError, "head_columns = 3"):
            ns.read_spikes(junk, head_columns=3)

    @unittest.skipUnless(ns.NATIVE and "hdf5" in ns.FEATURES, "a build without the hdf5 feature")
    def test_hdf5_event_files_round_trip(self):
        ev = random_events(2000, 30, 40, seed=8)
        t = (np.asarray(ev.t_ns) // 1000) * 1000
        ev = ns.Events(t, ev.x, ev.y, ev.polarity, 40, 30)
        f = self.path / "e.h5"
        self.assertEqual(ns.write_events(f, ev), 2000)
        back = ns.read_events(f)
        np.testing.assert_array_equal(back.t_ns, ev.t_ns)
        np.testing.assert_array_equal(back.x, ev.x)

    def test_aedat4_files_carry_aps_frames(self):
        ev = random_events(300, 6, 8, seed=9)
        t0, t1 = int(ev.t_ns[0]), int(ev.t_ns[-1])
        times = [t0 // 1000 * 1000, (t0 + t1) // 2000 * 1000, t1 // 1000 * 1000 + 5000]
        frames = np.random.default_rng(3).random((3, 6, 8)).astype(np.float32)
        f = self.path / "f.aedat4"
        ns.write_events(f, ev, aps=(times, frames))
        t, back = ns.read_aps_frames(f)
        np.testing.assert_array_equal(t, times)
        np.testing.assert_allclose(back, frames, atol=0.5 / 65535 + 1e-7)
        streamed = list(ns.ApsFrameReader(f))
        self.assertEqual([s[0] for s in streamed], times)
        np.testing.assert_array_equal(np.stack([s[1] for s in streamed]), back)
        self.assertEqual(len(ns.read_events(f)), 300)
        with self.assertRaisesRegex(ns.InputError, "one time a frame"):
            ns.write_events(f, ev, aps=(times[:2], frames))
        with self.assertRaisesRegex(ns.ConfigError, "AEDAT 4 files only"):
            ns.write_events(self.path / "e.txt", ev, aps=(times, frames))
        plain = self.path / "e.aedat4"
        ns.write_events(plain, ev)
        t, none = ns.read_aps_frames(plain)
        self.assertEqual((t.shape, none.shape), ((0,), (0, 0, 0)))


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
@unittest.skipUnless(os.environ.get("NEUSPIKE_RECORDING"), "no recording written by neuspike simulate")
class SimulatedRecordingTest(unittest.TestCase):
    """What `neuspike simulate bright-slow --planes 100` wrote (tests/python.rs), read back."""

    def setUp(self):
        self.dir = Path(os.environ["NEUSPIKE_RECORDING"])
        self.sim = ns.simulate("bright-slow", 100, seed=1, truth_every=20, events=False)

    def test_the_spikes_and_the_truth_are_simulates(self):
        spikes = ns.read_spikes(self.dir / "spikes.dat")
        np.testing.assert_array_equal(spikes.packed, self.sim.spikes.packed)
        planes, frames = ns.read_truth(self.dir / "ground-truth")
        np.testing.assert_array_equal(planes, self.sim.truth_planes)
        np.testing.assert_allclose(frames, self.sim.truth, atol=0.5 / 255 + 1e-6)

    def test_info_summarises_each_file(self):
        s = ns.info(self.dir / "spikes.dat")
        self.assertEqual((s["kind"], s["planes"], s["width"]), ("spikes", 100, 400))
        self.assertEqual(s["spikes"], int(self.sim.spikes.unpack().sum(dtype=np.int64)))
        e = ns.info(self.dir / "events.aedat4")
        self.assertEqual((e["kind"], e["format"]), ("events", "AEDAT 4"))
        self.assertEqual(e["events"], len(ns.read_events(self.dir / "events.aedat4")))
        self.assertIn("AEDAT 4", e["text"])
        with self.assertRaisesRegex(ns.FormatError, "nothing-here"):
            ns.read_truth(self.dir / "nothing-here")


REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
@unittest.skipUnless(REAL.is_dir(), f"no real recordings in {REAL}")
class RealRecordingsTest(unittest.TestCase):
    """The recordings of ../shared/data/real, with the facts its README states."""

    def test_the_vidar_car(self):
        s = ns.read_spikes(REAL / "vidar-car-400x250.dat")
        self.assertEqual((len(s), s.width, s.height), (200, 400, 250))
        self.assertEqual(int(s.unpack().sum(dtype=np.int64)), 7_324_316)
        self.assertAlmostEqual(float(ns.tfp(s).mean()), 7_324_316 / (200 * 100_000), places=5)

    def test_the_davis240c_text(self):
        ev = ns.read_events(REAL / "davis240c-shapes-rotation-events.txt", width=240, height=180)
        self.assertEqual(len(ev), 20_000)
        first = (int(ev.t_ns[0]), int(ev.x[0]), int(ev.y[0]), int(ev.polarity[0]))
        self.assertEqual(first, (2_097_134_001, 162, 27, -1))
        self.assertEqual((int(np.max(ev.x)), int(np.max(ev.y))), (236, 179))

    def test_the_prophesee_raw(self):
        ev = ns.read_events(REAL / "prophesee-evt2-640x480.raw", width=640, height=480)
        self.assertEqual(len(ev), 521_252)
        self.assertEqual((int(ev.t_ns[0]), int(ev.t_ns[-1])), (913_716_224_000, 913_812_095_000))
        self.assertEqual(float(ns.voxel_grid(ev, 1).sum()), float(np.asarray(ev.polarity, np.int64).sum()))


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class SimulateTest(unittest.TestCase):
    def test_a_seed_gives_the_same_recording(self):
        a = ns.simulate("bright-fast", 60, seed=7)
        b = ns.simulate("bright-fast", 60, seed=7)
        c = ns.simulate("bright-fast", 60, seed=8)
        np.testing.assert_array_equal(a.spikes.packed, b.spikes.packed)
        np.testing.assert_array_equal(a.events.t_ns, b.events.t_ns)
        np.testing.assert_array_equal(a.truth, b.truth)
        self.assertFalse(np.array_equal(a.spikes.packed, c.spikes.packed))
        self.assertEqual(a.truth.shape, (3, 250, 400))
        np.testing.assert_array_equal(a.truth_planes, [0, 20, 40])
        np.testing.assert_array_equal(a.truth_t_ns, [0, 1_000_000, 2_000_000])
        self.assertGreater(len(a.events), 0)
        self.assertEqual(a.events.t_end_ns, 60 * 50_000)

    def test_a_scene_file_is_the_builtin_it_copies(self):
        path = Path(__file__).resolve().parents[2] / "graphs" / "scenes" / "bright-fast.yml"
        if not path.is_file():
            self.skipTest(f"no {path}")
        a = ns.simulate(str(path), 40, seed=2, truth_every=20)
        b = ns.simulate("bright-fast", 40, seed=2, truth_every=20)
        np.testing.assert_array_equal(a.spikes.packed, b.spikes.packed)
        np.testing.assert_array_equal(a.truth, b.truth)

    def test_tfp_sees_the_truth(self):
        sim = ns.simulate("bright-static", 200, truth_every=100, events=False)
        self.assertIsNone(sim.events)
        rate = ns.tfp(sim.spikes.window(0, 200)) * sim.spikes.lum_per_rate
        self.assertGreater(ns.psnr(rate, sim.truth[1]), 25.0)

    def test_frames_the_user_passes_are_the_scene(self):
        frames = np.stack([np.full((20, 30), v, np.float32) for v in (0.2, 0.6)])
        sim = ns.simulate(
            planes=400,
            frames=frames,
            frame_dt_ns=10_000_000,
            truth_every=100,
            spike_camera={"random_init": False, "fpn_cap": False},
            event_camera={"theta_on": 0.2, "theta_sigma": 0.0},
        )
        self.assertEqual((sim.spikes.width, sim.spikes.height), (30, 20))
        self.assertEqual((sim.events.width, sim.events.height), (30, 20))
        # Planes 0, 100, 200, 300 at 0, 5, 10, 15 ms: the first frame, halfway, the second, held.
        np.testing.assert_allclose(sim.truth.mean(axis=(1, 2)), [0.2, 0.4, 0.6, 0.6], atol=1e-6)
        self.assertEqual(float(np.ptp(sim.truth[1])), 0.0)
        self.assertTrue((np.asarray(sim.events.polarity) == 1).all())
        rate = ns.tfp(sim.spikes.window(0, 100)) * sim.spikes.lum_per_rate
        # The mean light of a ramp from 0.2 to 0.4, counted in whole spikes: within one of 30.
        self.assertLessEqual(abs(float(rate.mean()) - 0.3), 0.0101)

    def test_the_dvs_on_frames_is_the_scene_dvs_without_the_spike_camera(self):
        rng = np.random.default_rng(2)
        base = (0.2 + 0.6 * rng.random((24, 60))).astype(np.float32)
        frames = np.stack([base[:, k : k + 40] for k in range(12)])
        camera = {"theta_sigma": 0.0}
        ev = ns.frames_to_events(frames, 1_000_000, event_camera=camera)
        self.assertEqual((ev.width, ev.height), (40, 24))
        self.assertGreater(len(ev), 100)
        t = np.asarray(ev.t_ns)
        self.assertTrue((np.diff(t) >= 0).all() and t[0] >= 0 and t[-1] < 11_000_000)
        again = ns.frames_to_events(frames, 1_000_000, event_camera=camera)
        np.testing.assert_array_equal(again.t_ns, ev.t_ns)
        # A brightening pixel fires ON events as many as its log change holds (theta 0.2).
        ramp = np.stack([np.full((1, 1), v, np.float32) for v in (0.1, 0.1 * np.exp(0.9))])
        up = ns.frames_to_events(ramp, 1_000, event_camera=camera | {"theta_on": 0.2})
        self.assertEqual(list(np.asarray(up.polarity)), [1, 1, 1, 1])
        with self.assertRaisesRegex(ns.InputError, "frame 1 row 0 column 0 is NaN"):
            ns.frames_to_events(np.stack([base, np.full_like(base, np.nan)]), 1000)
        with self.assertRaisesRegex(ns.ConfigError, "homography applies to a simulated scene"):
            ns.frames_to_events(frames, 1000, event_camera={"homography": "1,0,0,0,1,0,0,0,1"})
        sim = ns.simulate(frames=frames, frame_dt_ns=1_000_000, planes=200, spikes=False, truth_every=100,
                          event_camera=camera)
        self.assertIsNone(sim.spikes)
        self.assertEqual(sim.truth.shape, (2, 24, 40))
        self.assertGreater(len(sim.events), 100)

    def test_settings_are_the_nodes_arguments(self):
        phi1 = ns.simulate("bright-static", 50, events=False, truth_every=0)
        phi2 = ns.simulate("bright-static", 50, events=False, truth_every=0, spike_camera={"phi": 2.0})
        self.assertLess(ns.tfp(phi2.spikes).mean(), 0.6 * ns.tfp(phi1.spikes).mean())
        self.assertAlmostEqual(phi2.spikes.lum_per_rate, 2 * phi1.spikes.lum_per_rate)
        # Random spikes add spikes and take none away: 1,000 Hz at 20 kHz is 5 % of pixel-ticks.
        noisy = ns.simulate("bright-static", 50, events=False, truth_every=0, spike_camera={"random_spike_hz": 1000})
        clean, more = phi1.spikes.unpack(), noisy.spikes.unpack()
        self.assertTrue(np.all(more >= clean))
        self.assertAlmostEqual(float(more.mean() - clean.mean()), 0.05 * (1 - clean.mean()), delta=0.01)
        with self.assertRaisesRegex(ns.ConfigError, "random-spike-hz"):
            ns.simulate(spike_camera={"random_spike_hz": 20_000})
        with self.assertRaisesRegex(ns.ConfigError, "spike_camera: unexpected argument '--bogus'"):
            ns.simulate(spike_camera={"bogus": 1})
        with self.assertRaisesRegex(ns.ConfigError, "phi` = -1 is invalid"):
            ns.simulate(spike_camera={"phi": -1})
        with self.assertRaisesRegex(ns.ConfigError, "scene nowhere"):
            ns.simulate("nowhere")
        with self.assertRaisesRegex(ns.ConfigError, "planes = 0"):
            ns.simulate(planes=0)
        with self.assertRaisesRegex(ns.ConfigError, "truth_every = 1: 100000 frames"):
            ns.simulate(planes=100_000, truth_every=1, spikes=False, events=False)
        frames = np.zeros((2, 3, 4))  # float64, converted
        self.assertEqual(ns.simulate(frames=frames, planes=4, events=False).spikes.width, 4)
        with self.assertRaisesRegex(ns.ConfigError, "more than the 4294967296 one call makes"):
            ns.simulate(planes=400_000)


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class SamplesTest(unittest.TestCase):
    def setUp(self):
        self.samples = ns.Samples(size=16, per_cell=2, seed=5, also=["voxel_grid"])

    def test_a_sample_is_its_index_and_seed(self):
        s = self.samples
        self.assertEqual(len(s), 50)
        a, b = s[7], s[7]
        for k in ("spike", "events", "truth", "tfp", "tfi"):
            np.testing.assert_array_equal(a[k], b[k])
        self.assertEqual(a["spike"].shape, (32, 16, 16))
        self.assertEqual(a["truth"].shape, (16, 16))
        self.assertEqual(a["also"]["voxel_grid"].shape, (5, 16, 16))
        self.assertFalse(np.array_equal(s[8]["truth"], a["truth"]))
        other = ns.Samples(size=16, per_cell=2, seed=6)
        self.assertFalse(np.array_equal(other[7]["truth"], a["truth"]))
        np.testing.assert_array_equal(s[-43]["truth"], a["truth"])
        with self.assertRaises(IndexError):
            s[50]

    def test_a_batch_is_its_samples_stacked(self):
        b = self.samples.batch([3, 9, 3])
        self.assertEqual(b["spike"].shape, (3, 32, 16, 16))
        self.assertEqual(b["also"]["voxel_grid"].shape, (3, 5, 16, 16))
        for j, i in enumerate([3, 9, 3]):
            one = self.samples[i]
            np.testing.assert_array_equal(b["events"][j], one["events"])
            self.assertEqual(b["lum_per_rate"][j], one["lum_per_rate"])
            self.assertEqual(b["texture"][j], one["texture"])
        with self.assertRaises(IndexError):
            self.samples.batch([0, 99])
        with self.assertRaisesRegex(ns.InputError, "indices: none given"):
            self.samples.batch([])
        np.testing.assert_array_equal(self.samples.batch([-1])["truth"][0], self.samples[49]["truth"])

    def test_options_are_the_dataset_commands(self):
        with self.assertRaisesRegex(ns.ConfigError, "--size = 4 is invalid"):
            ns.Samples(size=4)
        with self.assertRaisesRegex(ns.ConfigError, "unexpected argument '--bogus'"):
            ns.Samples(bogus=1)
        with self.assertRaisesRegex(ns.ConfigError, "give one or the other"):
            ns.Samples(profile="vidar")
        fixed = ns.Samples(size=16, per_cell=1, profile="vidar", randomise_camera=False)
        self.assertIn("16x16", repr(fixed))
        self.assertNotIn("cameras drawn", repr(fixed))

    def test_workers_forked_or_spawned_make_the_same_samples(self):
        want = [self.samples[i]["truth"] for i in (4, 11)]
        for method in ("fork", "spawn"):
            with multiprocessing.get_context(method).Pool(2) as pool:
                got = pool.map_async(truth_in_worker, [(self.samples, 4), (self.samples, 11)]).get(timeout=120)
            for g, w in zip(got, want):
                np.testing.assert_array_equal(g, w, err_msg=method)

    def test_the_stream_shares_each_epoch_between_workers(self):
        from neuspike.data import SampleDataset, SampleStream

        stream = SampleStream(self.samples, batch_size=8, seed=1)
        first = stream.order()
        self.assertEqual(sorted(first), list(range(50)))
        self.assertEqual([len(b) for b in stream.batches()], [8] * 6 + [2])
        stream.set_epoch(1)
        self.assertNotEqual(stream.order(), first)
        stream.set_epoch(0)
        self.assertEqual(stream.order(), first)
        got = next(iter(stream))
        np.testing.assert_array_equal(np.asarray(got["truth"][0]), self.samples[first[0]]["truth"])
        self.assertEqual(len(SampleDataset(self.samples)), 50)

    @unittest.skipUnless(importlib.util.find_spec("torch"), "torch is not installed")
    def test_a_torch_dataloader_with_forked_and_spawned_workers(self):
        import torch
        from torch.utils.data import DataLoader

        from neuspike.data import SampleDataset, SampleStream

        # The parent uses the pool first, as a training script does before its loader starts.
        want = self.samples.batch(list(range(8)))["truth"]
        for method in ("fork", "spawn"):
            loader = DataLoader(SampleDataset(self.samples), batch_size=4, num_workers=2,
                                multiprocessing_context=method, timeout=120)
            got = torch.cat([b["truth"] for b, _ in zip(loader, range(2))])
            np.testing.assert_array_equal(got.numpy(), want, err_msg=method)
            stream = DataLoader(SampleStream(self.samples, batch_size=5, shuffle=False), batch_size=None,
                                num_workers=2, multiprocessing_context=method, timeout=120)
            # Every sample once, shared between the two workers.
            seen = sorted(float(t.sum()) for b in stream for t in b["truth"].numpy())
            every = sorted(float(t.sum()) for t in self.samples.batch(list(range(50)))["truth"])
            self.assertEqual(seen, every, method)

    @unittest.skipUnless(os.environ.get("NEUSPIKE_DATASET_DIR"), "no set written by neuspike dataset")
    def test_the_samples_are_those_neuspike_dataset_writes(self):
        # tests/python.rs writes a small set (the dataset crate's tiny options) and names it.
        d = Path(os.environ["NEUSPIKE_DATASET_DIR"])
        s = ns.Samples(size=16, per_cell=1, seed=7, randomise_camera=False)
        b = s.batch(list(range(len(s))))
        for k in ("spike", "events", "truth", "tfp", "tfi"):
            disk = np.concatenate([np.load(d / f"{i:03}" / f"{k}.npy") for i in range(3)])
            np.testing.assert_array_equal(b[k], disk, err_msg=k)


TFP_GRAPH = {
    "nodes": [
        {"id": "spike-source", "path": "neuspike-spike-source", "outputs": ["spikes"],
         "args": "--scene bright-slow --chunk-planes 20 --seed 1 --max-planes 100"},
        {"id": "align", "path": "neuspike-align", "args": "--window-planes 33 --stride-planes 20",
         "inputs": {"spikes": "spike-source/spikes"}, "outputs": ["windows"]},
        {"id": "represent", "path": "neuspike-represent", "args": "--tfp-planes 33",
         "inputs": {"windows": "align/windows"}, "outputs": ["tfp"]},
        {"id": "infer", "path": "neuspike-infer", "args": "--method tfp",
         "inputs": {"representation": "represent/tfp"}, "outputs": ["frames"]},
    ]
}


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class ReconstructTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.sim = ns.simulate("bright-slow", 100, seed=1, truth_every=20, event_camera={"width": 400, "height": 250})

    def test_tfp_and_tfi_frames_are_the_kernels_calibrated(self):
        s = self.sim.spikes
        window = s.window(4, 37)  # the 33 planes around plane 20, the first frame's
        for method, kernel in (("tfp", ns.tfp(window)), ("tfi", ns.tfi(window, 16))):
            r = ns.reconstruct(s, method=method)
            np.testing.assert_array_equal(r["t_ref_ns"], [1_000_000, 2_000_000, 3_000_000, 4_000_000])
            np.testing.assert_array_equal(r["frames"][0], np.clip(kernel * s.lum_per_rate, 0, 1))
            self.assertEqual(r["method"], method)

    def test_a_recordings_representations_are_the_kernels_per_window(self):
        sim = self.sim
        r = ns.represent(sim.spikes, sim.events, kinds=["tfp", "isi", "spike_repr", "voxel_grid", "stp"])
        np.testing.assert_array_equal(r["t_ref_ns"], [1_000_000, 2_000_000, 3_000_000, 4_000_000])
        self.assertEqual(r["voxel_grid"].shape, (4, 5, 250, 400))
        window = sim.spikes.window(4, 37)
        np.testing.assert_array_equal(r["tfp"][0, 0], ns.tfp(window))
        np.testing.assert_array_equal(r["spike_repr"][0], ns.spike_representation(window, 16))
        isi, valid = ns.isi(window, 16)
        np.testing.assert_array_equal(r["isi"][0], np.stack([isi, valid.astype(np.float32)]))
        with self.assertRaisesRegex(ns.ConfigError, 'kinds: "nope" is not one of tfp'):
            ns.represent(sim.spikes, kinds=["nope"])

    def test_every_method_makes_its_frames(self):
        sim = self.sim
        for method in ("tfstp", "hf", "cf", "fusion"):
            r = ns.reconstruct(sim.spikes, sim.events, method=method)
            self.assertEqual(r["frames"].shape, (4, 250, 400), method)
            self.assertTrue(np.isfinite(r["frames"]).all(), method)
        tfp = ns.reconstruct(sim.spikes, method="tfp")["frames"][1]
        fusion = ns.reconstruct(sim.spikes, sim.events, method="fusion")["frames"][1]
        self.assertGreater(ns.psnr(tfp, sim.truth[2]), 30.0)
        self.assertGreater(ns.psnr(fusion, sim.truth[2]), 10.0)

    @unittest.skipUnless(ns.NATIVE and ns.models(), "the shipped networks are not at hand")
    def test_the_networks_and_auto(self):
        sim = self.sim
        spike = ns.reconstruct(sim.spikes, method="learned", model="neuspike-spike-8")
        self.assertEqual(spike["frames"].shape, (4, 250, 400))
        self.assertGreater(ns.psnr(spike["frames"][1], sim.truth[2]), 30.0)
        fused = ns.reconstruct(sim.spikes, sim.events, method="learned", model="neuspike-fused-8")
        self.assertEqual(fused["frames"].shape, (4, 250, 400))
        auto = ns.reconstruct(sim.spikes, sim.events, method="auto", window_planes=33)
        self.assertEqual(len(auto["chosen"]), len(auto["frames"]))
        with self.assertRaisesRegex(ns.ConfigError, "model: reads events; pass events="):
            ns.reconstruct(sim.spikes, method="learned", model="neuspike-fused-8")

    def test_refusals_are_named(self):
        s = self.sim.spikes
        far = ns.Events([10**18], [0], [0], [1], 400, 250)
        with self.assertRaisesRegex(ns.InputError, "are both on one clock"):
            ns.reconstruct(s, far, method="hf")
        with self.assertRaisesRegex(ns.ConfigError, "method fusion: reads events"):
            ns.reconstruct(s, method="fusion")
        with self.assertRaisesRegex(ns.ConfigError, 'unknown reconstruction method "nope"'):
            ns.reconstruct(s, method="nope")
        with self.assertRaisesRegex(ns.ConfigError, "unexpected argument '--bogus'"):
            ns.reconstruct(s, self.sim.events, method="cf", infer="--bogus 1")
        with self.assertRaisesRegex(ns.ConfigError, "method learned: pass model="):
            ns.reconstruct(s, method="learned")

    def test_a_graph_runs_in_process_as_the_same_pipeline(self):
        out = ns.run_graph(TFP_GRAPH, collect=["spike-source/spikes", "infer/frames"])
        packed = np.concatenate([c.packed for c in out["spike-source/spikes"]])
        np.testing.assert_array_equal(packed, self.sim.spikes.packed)
        r = ns.reconstruct(self.sim.spikes, method="tfp")
        frames = out["infer/frames"]
        self.assertEqual([f["t_ref_ns"] for f in frames], list(r["t_ref_ns"]))
        for i, f in enumerate(frames):
            np.testing.assert_array_equal(f["data"], r["frames"][i])
        self.assertIn("| align |", out["stages"])
        bad = {"nodes": [dict(TFP_GRAPH["nodes"][0], args="--scene nowhere")]}
        with self.assertRaisesRegex(ns.ConfigError, "nowhere"):
            ns.run_graph(bad)


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class MetricsTest(unittest.TestCase):
    def test_psnr_gain_ssim_entropy(self):
        rng = np.random.default_rng(9)
        gt = rng.random((32, 40)).astype(np.float32)
        x = np.clip(gt + 0.05 * rng.standard_normal(gt.shape), 0, 1).astype(np.float32)
        mse = np.mean((x.astype(np.float64) - gt) ** 2)
        self.assertAlmostEqual(ns.psnr(x, gt), 10 * np.log10(1 / mse), places=6)
        self.assertEqual(ns.psnr(gt, gt), float("inf"))
        self.assertAlmostEqual(ns.gain(0.5 * gt, gt), 2.0, places=5)
        self.assertEqual(ns.psnr_after_gain(0.5 * gt, gt), float("inf"))
        self.assertAlmostEqual(ns.ssim(gt, gt), 1.0, places=9)
        self.assertLess(ns.ssim(x, gt), 0.99)
        self.assertEqual(ns.entropy_2d(np.zeros((8, 8), np.float32)), 0.0)
        self.assertGreater(ns.entropy_2d(gt), 8.0)
        self.assertAlmostEqual(ns.psnr(x.astype(np.float64)[:, ::-1][:, ::-1], gt), ns.psnr(x, gt))

    def test_shapes_must_agree(self):
        with self.assertRaisesRegex(ns.InputError, "image is 2x3, ground truth is 3x2"):
            ns.psnr(np.zeros((2, 3)), np.zeros((3, 2)))


@unittest.skipUnless(ns.NATIVE, "neuspike's native module is not built")
class ThreadsTest(unittest.TestCase):
    def tearDown(self):
        ns.set_threads(0)

    def test_the_thread_count_is_settable(self):
        ns.set_threads(1)
        self.assertEqual(ns.threads(), 1)
        one = tfp_in_worker(3)
        ns.set_threads(3)
        self.assertEqual(ns.threads(), 3)
        np.testing.assert_array_equal(tfp_in_worker(3), one)
        with self.assertRaisesRegex(ns.ConfigError, "threads = 5000"):
            ns.set_threads(5000)

    def test_kernels_release_the_gil(self):
        # Python threads each run kernels; with the GIL held they would still finish, so this
        # checks the results under concurrency, not the timing.
        sim = ns.simulate("bright-slow", 64, events=False, truth_every=0)
        want = ns.tfp(sim.spikes)
        got = [None] * 4

        def work(i):
            got[i] = ns.tfp(sim.spikes)

        ts = [threading.Thread(target=work, args=(i,)) for i in range(4)]
        for t in ts:
            t.start()
        for t in ts:
            t.join()
        for g in got:
            np.testing.assert_array_equal(g, want)

    def test_forked_and_spawned_workers_run_kernels(self):
        # The parent's pool runs first, as a DataLoader's main process does before its workers.
        want = [tfp_in_worker(s) for s in (1, 2)]
        for method in ("fork", "spawn"):
            ctx = multiprocessing.get_context(method)
            with ctx.Pool(2) as pool:
                got = pool.map_async(tfp_in_worker, [1, 2]).get(timeout=120)
            for g, w in zip(got, want):
                np.testing.assert_array_equal(g, w, err_msg=method)


if __name__ == "__main__":
    unittest.main()
