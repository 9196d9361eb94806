"""Reads a run recorded by the publish node (``--mcap``) with programs that share no code with
neuspike: the MCAP library of its authors (``mcap``) and rosbags' CDR deserialiser. Checks that
it is a ROS 2 bag (profile ``ros2``, schema ``sensor_msgs/msg/Image`` in ``ros2msg``, messages in
``cdr``) and writes the images of ``--topic`` in order, as ros2_image_subscriber.py does:
``images.bin`` (mono8 pixels), ``stamps.bin`` (int64 ns) into ``--out``, and ``report.json``.
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_typestore


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("bag")
    ap.add_argument("--topic", default="/neuspike/tfp")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    store = get_typestore(Stores.ROS2_JAZZY)
    images, stamps, problems = [], [], []
    arrow = 0
    with open(a.bag, "rb") as f:
        reader = make_reader(f)
        profile = reader.get_header().profile
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.topic == a.topic:
                if schema is None or schema.name != "sensor_msgs/msg/Image" or schema.encoding != "ros2msg":
                    problems.append(f"schema {schema and schema.name} {schema and schema.encoding}")
                    continue
                if channel.message_encoding != "cdr":
                    problems.append(f"message encoding {channel.message_encoding}")
                    continue
                msg = store.deserialize_cdr(message.data, "sensor_msgs/msg/Image")
                images.append(np.asarray(msg.data, np.uint8).reshape(msg.height, msg.width))
                stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            elif channel.message_encoding == "neuspike/messages/v1":
                arrow += 1
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (np.concatenate([i.ravel() for i in images]) if images else np.zeros(0, np.uint8)).tofile(out / "images.bin")
    np.array(stamps, np.int64).tofile(out / "stamps.bin")
    report = {"profile": profile, "images": len(images), "arrow_messages": arrow, "problems": problems[:10]}
    (out / "report.json").write_text(json.dumps(report))
    print(json.dumps(report))
    return 0 if profile == "ros2" and not problems else 1


if __name__ == "__main__":
    sys.exit(main())
