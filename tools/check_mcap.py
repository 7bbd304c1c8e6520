#!/usr/bin/env python3
"""Reads a stereolink recording (`send`/`receive --record FILE.mcap`) with an
outside reader, PyPI `mcap` + `mcap-ros2-support`, and checks it as ROS 2
tools will see it: each topic's message type, the images' sizes and
encodings, the cameras and the disparity's conventions, the baseline on
/tf_static once, and the time stamps (header.stamp equals the log time,
in order on each topic). Prints one JSON object (messages per topic, the
baseline, each topic's last stamp); exits 1 naming the first problem.

    python3 tools/check_mcap.py FILE.mcap --size 160x120 [--frames N] [--station NAME]

A gateway's recording holds each station's topics under /NAME (--station).
"""

import argparse
import json
import math
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

TYPES = {
    "/stereo/left/image_rect_color": "sensor_msgs/msg/Image",
    "/stereo/right/image_rect_color": "sensor_msgs/msg/Image",
    "/stereo/left/camera_info": "sensor_msgs/msg/CameraInfo",
    "/stereo/right/camera_info": "sensor_msgs/msg/CameraInfo",
    "/stereo/disparity": "stereo_msgs/msg/DisparityImage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/stereo/depth_report": "stereolink_msgs/msg/DepthReport",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def fail(why):
    print(f"check_mcap: {why}", file=sys.stderr)
    sys.exit(1)


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def check_image(topic, img, size, encoding, pixel):
    if (img.width, img.height) != size:
        fail(f"{topic}: {img.width}x{img.height}, expected {size[0]}x{size[1]}")
    if img.encoding != encoding or img.step != img.width * pixel:
        fail(f"{topic}: encoding {img.encoding}, step {img.step}")
    if len(img.data) != img.step * img.height:
        fail(f"{topic}: {len(img.data)} data bytes for step {img.step}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--size", required=True, help="WxH of the views")
    ap.add_argument("--frames", type=int, default=1, help="least number of frames")
    ap.add_argument("--station", help="a gateway's station: its topics are under /NAME")
    a = ap.parse_args()
    ns = f"/{a.station}" if a.station else ""
    types = {(t if t == "/tf_static" else ns + t): ty for t, ty in TYPES.items()}
    size = tuple(int(v) for v in a.size.split("x"))
    counts = {t: 0 for t in types}
    last = {}
    info = {}
    with open(a.file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        if reader.get_header().profile != "ros2":
            fail(f"profile {reader.get_header().profile!r}, expected 'ros2'")
        for schema, channel, message, msg in reader.iter_decoded_messages():
            topic = channel.topic
            if topic not in types:
                fail(f"unexpected topic {topic}")
            if schema.name != types[topic] or schema.encoding != "ros2msg":
                fail(f"{topic}: schema {schema.name} ({schema.encoding})")
            if channel.message_encoding != "cdr":
                fail(f"{topic}: message encoding {channel.message_encoding}")
            counts[topic] += 1
            header = msg.transforms[0].header if topic == "/tf_static" else msg.header
            if stamp_ns(header) != message.log_time:
                fail(f"{topic}: header.stamp {stamp_ns(header)} != log time {message.log_time}")
            if message.log_time < last.get(topic, 0):
                fail(f"{topic}: time stamps go back")
            last[topic] = message.log_time
            if topic.endswith("image_rect_color"):
                check_image(topic, msg, size, "rgb8", 3)
            elif topic.endswith("camera_info"):
                if (msg.width, msg.height) != size or len(msg.k) != 9 or len(msg.p) != 12:
                    fail(f"{topic}: {msg.width}x{msg.height}, K {len(msg.k)}, P {len(msg.p)}")
                info[topic] = msg
            elif topic == "/stereo/disparity":
                check_image(topic, msg.image, size, "32FC1", 4)
                if not (msg.f > 0 and msg.t > 0 and msg.min_disparity < msg.max_disparity):
                    fail(f"{topic}: f {msg.f}, t {msg.t}, range {msg.min_disparity}..{msg.max_disparity}")
                values = memoryview(bytes(msg.image.data)).cast("f")
                valid = [v for v in values if v >= msg.min_disparity]
                if not valid or max(valid) > msg.max_disparity or any(map(math.isnan, values)):
                    fail(f"{topic}: values outside {msg.min_disparity}..{msg.max_disparity}")
            elif topic == "/tf_static":
                t = msg.transforms[0]
                if t.transform.translation.x <= 0 or t.transform.rotation.w != 1.0:
                    fail(f"{topic}: {t.transform}")
            elif topic == "/diagnostics":
                if not msg.status or not msg.status[0].values:
                    fail(f"{topic}: no values")
    for topic in types:
        if topic.startswith(ns + "/stereo/") and counts[topic] < a.frames:
            fail(f"{topic}: {counts[topic]} messages, expected at least {a.frames}")
    if counts["/tf_static"] != 1:
        fail(f"/tf_static: {counts['/tf_static']} messages, expected 1")
    left, right = info[ns + "/stereo/left/camera_info"], info[ns + "/stereo/right/camera_info"]
    f, tx = right.p[0], right.p[3]
    if left.p[3] != 0.0 or not (f > 0 and tx < 0):
        fail(f"camera_info: left Tx {left.p[3]}, right f {f} Tx {tx}")
    print(json.dumps({"messages": counts, "baseline_m": -tx / f, "last_stamp_ns": last}))


if __name__ == "__main__":
    main()
