"""An independent ROS 2 event-camera driver over zenoh, as rmw_zenoh sends samples, and a check of
what neuspike made of it. No neuspike code: eclipse-zenoh, rosbags (CDR, with
event_camera_msgs/msg/EventPacket registered from its definition), pyarrow and numpy.

It listens on ``--listen``; once neuspike's subscription token for ``--topic`` appears, it
publishes ``--packets`` EventPackets of random events (EVT 3.0 words made here, time in µs;
each sample with its 33-byte rmw_zenoh attachment), then reads neuspike's EventBatch messages on
``--key`` until their end-of-stream marker and checks them event for event against what it sent.
It prints ``ready`` once listening, and a JSON report at the end; it exits 1 on a mismatch.
"""

import argparse
import json
import struct
import sys
import threading
import time

import numpy as np
import pyarrow as pa
import zenoh
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

EVENT_PACKET = """
std_msgs/Header header
uint32 height
uint32 width
uint64 seq
uint64 time_base
string encoding
bool is_bigendian
uint8[] events
"""
TYPE = "event_camera_msgs::msg::dds_::EventPacket_"
HASH = "RIHS01_d6fa176260b1f37e5a40845305315e150a0f18191241eb64f407442aa29844aa"


def evt3_words(t_us, x, y, p, state):
    """EVT 3.0: TIME_HIGH (0x8) and TIME_LOW (0x6) when they change, ADDR_Y (0x0) when the row
    changes, one ADDR_X (0x2, polarity bit 11) an event. ``state`` carries across packets, as a
    driver's word stream does."""
    words = []
    for t, xx, yy, pp in zip(t_us, x, y, p):
        high, low = (int(t) >> 12) & 0xFFF, int(t) & 0xFFF
        if state.get("high") != high:
            words.append(0x8000 | high)
            state["high"] = high
            state["low"] = None
        if state.get("low") != low:
            words.append(0x6000 | low)
            state["low"] = low
        if state.get("y") != yy:
            words.append(0x0000 | int(yy))
            state["y"] = int(yy)
        words.append(0x2000 | (0x800 if pp > 0 else 0) | int(xx))
    return np.array(words, "<u2").tobytes()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--listen", required=True)
    ap.add_argument("--topic", default="/event_camera/events")
    ap.add_argument("--key", default="neuspike/ros2/events")
    ap.add_argument("--packets", type=int, default=100)
    ap.add_argument("--per-packet", type=int, default=400)
    ap.add_argument("--timeout", type=float, default=120.0)
    a = ap.parse_args()

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(EVENT_PACKET, "event_camera_msgs/msg/EventPacket"))
    EventPacket = store.types["event_camera_msgs/msg/EventPacket"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]

    width, height = 346, 260
    rng = np.random.default_rng(3)
    n = a.packets * a.per_packet
    # Times in µs from 0.1 s on, non-decreasing, several events sharing a time.
    t_us = 100_000 + np.cumsum(rng.integers(0, 3, n))
    x = rng.integers(0, width, n).astype(np.uint16)
    y = rng.integers(0, height, n).astype(np.uint16)
    p = np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8)

    lock = threading.Lock()
    got = {"t": [], "x": [], "y": [], "p": [], "eos": None, "batches": 0, "seqs": []}

    def on_batch(sample):
        reader = pa.ipc.open_stream(sample.payload.to_bytes())
        header = {k.decode(): v.decode() for k, v in reader.schema.metadata.items()}
        col = reader.read_next_batch().column(0)
        with lock:
            if header.get("eos") == "b:true":
                got["eos"] = int(header["count"][2:])
                return
            got["batches"] += 1
            got["seqs"].append(int(header["seq"][2:]))
            got["t"].append(col.field("t_ns").to_numpy())
            got["x"].append(col.field("x").to_numpy())
            got["y"].append(col.field("y").to_numpy())
            got["p"].append(col.field("polarity").to_numpy())

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([a.listen]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    topic = a.topic.strip("/")
    with zenoh.open(conf) as session:
        sub = session.declare_subscriber(a.key, on_batch)  # noqa: F841 (kept alive)
        pub = session.declare_publisher(
            f"0/{topic}/{TYPE}/{HASH}", congestion_control=zenoh.CongestionControl.BLOCK
        )
        print("ready", flush=True)
        # Wait for neuspike's subscription to announce itself, as ROS 2 tools see it.
        deadline = time.monotonic() + a.timeout
        mangled = "%" + topic.replace("/", "%")
        while time.monotonic() < deadline:
            tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/**") if r.ok]
            if any("/MS/" in k and mangled in k for k in tokens):
                break
            time.sleep(0.1)
        else:
            print("neuspike's subscription never appeared", file=sys.stderr)
            return 1
        time.sleep(0.3)
        gid = bytes(range(16))
        state = {}
        for k in range(a.packets):
            s = slice(k * a.per_packet, (k + 1) * a.per_packet)
            words = evt3_words(t_us[s], x[s], y[s], p[s], state)
            now = time.time_ns()
            msg = EventPacket(
                header=Header(stamp=Time(sec=now // 10**9, nanosec=now % 10**9), frame_id="dvs"),
                height=height,
                width=width,
                seq=k,
                time_base=0,
                encoding="evt3",
                is_bigendian=False,
                events=np.frombuffer(words, np.uint8),
            )
            cdr = bytes(store.serialize_cdr(msg, "event_camera_msgs/msg/EventPacket"))
            attachment = struct.pack("<qqB", k + 1, now, 16) + gid
            pub.put(cdr, attachment=attachment)
        while time.monotonic() < deadline:
            with lock:
                if got["eos"] is not None:
                    break
            time.sleep(0.1)

    with lock:
        cat = lambda k, dt: np.concatenate(got[k]).astype(dt) if got[k] else np.zeros(0, dt)  # noqa: E731
        rt, rx, ry, rp = cat("t", np.int64), cat("x", np.uint16), cat("y", np.uint16), cat("p", np.int8)
        report = {
            "sent_events": int(n),
            "received_events": int(len(rt)),
            "batches": got["batches"],
            "eos_count": got["eos"],
            "seqs_in_order": got["seqs"] == list(range(len(got["seqs"]))),
            "times_equal": bool(len(rt) == n and np.array_equal(rt, t_us * 1000)),
            "places_equal": bool(len(rx) == n and np.array_equal(rx, x) and np.array_equal(ry, y)),
            "polarities_equal": bool(len(rp) == n and np.array_equal(rp, p)),
        }
    print(json.dumps(report), flush=True)
    ok = report["times_equal"] and report["places_equal"] and report["polarities_equal"]
    ok = ok and report["seqs_in_order"] and report["eos_count"] == report["batches"]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
