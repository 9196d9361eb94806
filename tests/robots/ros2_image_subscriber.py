"""An independent ROS 2 image subscriber over zenoh, as rmw_zenoh delivers samples: no neuspike
code, only eclipse-zenoh, rosbags (its CDR deserialiser and Jazzy's type store) and pyarrow.

It listens on ``--listen``, subscribes to the rmw_zenoh data key of ``--topic``
(``<domain>/<topic>/sensor_msgs::msg::dds_::Image_/<hash>``) and to neuspike's own Arrow key
(``--key``), checks every sample's 33-byte attachment (sequence number, source time, GID length
16 and the GID), decodes every image, and stops once the Arrow stream's end-of-stream marker
came and no image arrived for a moment. It writes ``images.bin``, ``stamps.bin`` and
``seqs.bin`` (pixels, stamps, attachment sequence numbers) and ``report.json`` into ``--out``.
It prints ``ready`` once subscribed.
"""

import argparse
import json
import struct
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import zenoh
from rosbags.typesys import Stores, get_typestore


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--listen", required=True)
    p.add_argument("--topic", default="/neuspike/tfp")
    p.add_argument("--key", default="neuspike/live/tfp")
    p.add_argument("--domain", type=int, default=0)
    p.add_argument("--out", required=True)
    p.add_argument("--timeout", type=float, default=120.0)
    a = p.parse_args()

    store = get_typestore(Stores.ROS2_JAZZY)
    lock = threading.Lock()
    images, stamps, seqs, problems = [], [], [], []
    gids = set()
    state = {"eos": None, "arrow": 0, "last": time.monotonic()}

    def on_image(sample):
        att = sample.attachment
        raw = sample.payload.to_bytes()
        with lock:
            state["last"] = time.monotonic()
            if att is None:
                problems.append("an image without its attachment")
                return
            att = att.to_bytes()
            if len(att) != 33:
                problems.append(f"an attachment of {len(att)} bytes")
                return
            seq, source_ns, n = struct.unpack_from("<qqB", att)
            if n != 16:
                problems.append(f"GID length byte {n}")
            gids.add(att[17:])
            msg = store.deserialize_cdr(raw, "sensor_msgs/msg/Image")
            if msg.encoding != "mono8" or msg.step != msg.width:
                problems.append(f"encoding {msg.encoding} step {msg.step}")
                return
            images.append(np.asarray(msg.data, np.uint8).reshape(msg.height, msg.width))
            stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            seqs.append(seq)

    def on_arrow(sample):
        reader = pa.ipc.open_stream(sample.payload.to_bytes())
        header = {k.decode(): v.decode() for k, v in reader.schema.metadata.items()}
        with lock:
            state["last"] = time.monotonic()
            if header.get("eos") == "b:true":
                state["eos"] = int(header["count"][2:])
            else:
                state["arrow"] += 1

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([a.listen]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    topic = a.topic.strip("/")
    key = f"{a.domain}/{topic}/sensor_msgs::msg::dds_::Image_/*"
    with zenoh.open(conf) as session:
        subs = [  # noqa: F841 (kept alive)
            session.declare_subscriber(key, on_image),
            session.declare_subscriber(a.key, on_arrow),
        ]
        print("ready", flush=True)
        deadline = time.monotonic() + a.timeout
        while time.monotonic() < deadline:
            time.sleep(0.1)
            with lock:
                if state["eos"] is not None and time.monotonic() - state["last"] > 1.0:
                    break
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    with lock:
        # Raw little-endian arrays: images (uint8, one after the other), stamps and seqs (int64).
        for name, values, dtype in (("images", images, np.uint8), ("stamps", stamps, np.int64), ("seqs", seqs, np.int64)):
            arr = np.concatenate([np.ravel(v) for v in values]) if name == "images" and values else np.array(values, dtype)
            arr.astype(dtype).tofile(out / f"{name}.bin")
        report = {
            "images": len(images),
            "arrow_messages": state["arrow"],
            "arrow_eos_count": state["eos"],
            "publishers": len(gids),
            "problems": problems[:10],
        }
    (out / "report.json").write_text(json.dumps(report))
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
