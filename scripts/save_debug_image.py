#!/usr/bin/env python3
"""Keeps the localizer's match overlay with the most verified matches (red pixels) and writes it
as PNG when stopped (SIGINT) or after --timeout seconds. Pure Python (rospy, numpy, zlib): no
OpenCV module is needed.

Usage: save_debug_image.py --out FILE [--topic /localizer/debug_image] [--timeout 120]
"""
import argparse
import struct
import sys
import zlib

import numpy as np
import rospy
from sensor_msgs.msg import Image


def write_png(path, rgb):
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].tobytes() for y in range(h))

    def chunk(kind, data):
        c = kind + data
        return struct.pack(">I", len(data)) + c + struct.pack(">I", zlib.crc32(c) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path + ".partial", "wb") as f:
        f.write(png)
    import os
    os.replace(path + ".partial", path)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--topic", default="/localizer/debug_image")
    ap.add_argument("--timeout", type=float, default=120.0)
    a = ap.parse_args(rospy.myargv()[1:])
    best = {"red": -1, "rgb": None}

    def on_image(msg):
        if msg.encoding not in ("bgr8", "rgb8"):
            return
        img = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)
        img = img[:, : msg.width * 3].reshape(msg.height, msg.width, 3)
        rgb = img[:, :, ::-1] if msg.encoding == "bgr8" else img
        red = int(np.count_nonzero((rgb[:, :, 0] > 200) & (rgb[:, :, 1] < 60) & (rgb[:, :, 2] < 60)))
        if red > best["red"]:
            best["red"], best["rgb"] = red, np.ascontiguousarray(rgb)

    rospy.init_node("save_debug_image", anonymous=True)
    rospy.Subscriber(a.topic, Image, on_image, queue_size=2)
    end = rospy.Time.now() + rospy.Duration(a.timeout)
    while not rospy.is_shutdown() and rospy.Time.now() < end:
        rospy.sleep(0.1)
    if best["rgb"] is None:
        print("save_debug_image: no overlay arrived on " + a.topic, file=sys.stderr)
        return 1
    write_png(a.out, best["rgb"])
    print("save_debug_image: %s (%d red match pixels)" % (a.out, best["red"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
