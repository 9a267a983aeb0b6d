#!/usr/bin/env python3
"""Compares the loop closures the node published on a replay (a bag of
ground_texture_bow/LoopClosure, as scripts/backend_demo.sh records) with those of `gtbow slam`
on the same drive (its closures.csv): which image pairs both found, which only one did, and how
far apart the two relative poses are for the pairs they share.

The node's closures name images by stamp (--start + index / --rate, as gtbow_images_to_bag
stamps them); gtbow slam's by name (the drive split's order). The node's relative pose is in the
match camera's optical frame (x, -y, -theta of the view from above).

Usage: compare_closures.py CLOSURES_BAG SLAM_DIR DATASET [--start 1000] [--rate 20]
       [--markdown FILE] [--require-identical]
"""
import argparse
import csv
import math
import os
import sys

import rosbag


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("bag")
    ap.add_argument("slam_dir")
    ap.add_argument("dataset")
    ap.add_argument("--start", type=float, default=1000.0)
    ap.add_argument("--rate", type=float, default=20.0)
    ap.add_argument("--split", default="drive")
    ap.add_argument("--markdown")
    ap.add_argument("--require-identical", action="store_true",
                    help="exit 1 unless both found the same pairs")
    a = ap.parse_args()
    with open(os.path.join(a.dataset, "sequences", a.split + ".txt")) as f:
        names = [l.strip() for l in f if l.strip() and not l.startswith("#")]
    index = {n: i for i, n in enumerate(names)}

    def image_of(stamp):
        i = round((stamp.to_sec() - a.start) * a.rate)
        if i < 0 or i >= len(names):
            sys.exit(f"compare_closures: stamp {stamp.to_sec():.3f} is not an image of the drive")
        return i

    node = {}
    with rosbag.Bag(a.bag) as bag:
        for _, m, _ in bag.read_messages():
            if not hasattr(m, "match_from_query"):
                continue
            p = m.match_from_query
            node[(image_of(m.query_stamp), image_of(m.match_stamp))] = (p.x, -p.y, -p.theta)
    slam = {}
    with open(os.path.join(a.slam_dir, "closures.csv")) as f:
        for r in csv.DictReader(f):
            slam[(index[r["query_image"]], index[r["match_image"]])] = (
                float(r["x"]), float(r["y"]), float(r["theta"]))
    both = sorted(set(node) & set(slam))
    only_node = sorted(set(node) - set(slam))
    only_slam = sorted(set(slam) - set(node))
    dpos = [1000 * math.hypot(node[k][0] - slam[k][0], node[k][1] - slam[k][1]) for k in both]
    dang = [abs(math.degrees(math.remainder(node[k][2] - slam[k][2], 2 * math.pi))) for k in both]
    lines = [
        "| | closures |",
        "| --- | --- |",
        f"| the node (replay) | {len(node)} |",
        f"| gtbow slam | {len(slam)} |",
        f"| the same image pair | {len(both)} |",
        f"| only the node | {len(only_node)} |",
        f"| only gtbow slam | {len(only_slam)} |",
    ]
    if both:
        lines.append(f"| shared pairs: relative poses apart, max | {max(dpos):.4f} mm, "
                     f"{max(dang):.5f} deg |")
    text = "\n".join(lines)
    print(text)
    for k in (only_node + only_slam)[:10]:
        who = "node" if k in node else "slam"
        print(f"  only {who}: query {names[k[0]]}, match {names[k[1]]}")
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write(text + "\n")
    if a.require_identical and (only_node or only_slam):
        print("compare_closures: the two pipelines found different closures")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
