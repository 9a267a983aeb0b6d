#!/usr/bin/env python3
"""The keyframe poses of a saved map against a synthetic drive's ground truth.

Reads the keyframes of a map (`gtbow map-info --poses CSV`: id, stamp, has_pose, x, y, theta,
the camera footprint in the map's frame) and the drive's ground truth (DATASET/poses.csv and
sequences/SPLIT.txt), finds each keyframe's drive image by its stamp (the image i of the bag
that gtbow_images_to_bag wrote is stamped START + i / RATE), and prints the position error of
the keyframes, RMSE and maximum in mm, and the heading error. No alignment is fitted: a map
made by the localizer and pose_graph_backend is in the frame where the drive started (the
backend's map frame), which is the ground truth's.

With --max-rmse-mm and --max-mm it checks a claim, prints a verdict line, and exits 1 when it
fails (after printing the figures); exit 2 on bad input (a stamp that is no drive image's, a
keyframe without a pose, no keyframes).

Usage: map_pose_error.py MAP_POSES_CSV DATASET [--split drive] [--start 1000] [--rate 20]
                         [--first-id N] [--label TEXT] [--max-rmse-mm 1.0] [--max-mm 3.0]
                         [--json OUT]
"""
import argparse
import csv
import json
import math
import os
import sys


def fail(message):
    print("map_pose_error: " + message, file=sys.stderr)
    sys.exit(2)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("poses", help="gtbow map-info --poses CSV")
    ap.add_argument("dataset")
    ap.add_argument("--split", default="drive")
    ap.add_argument("--start", type=float, default=1000.0, help="stamp of the first image, s")
    ap.add_argument("--rate", type=float, default=20.0, help="images per second of the bag")
    ap.add_argument("--label", default="keyframes of the saved map")
    ap.add_argument("--first-id", type=int, default=0,
                    help="only the keyframes from this id on (a later session's)")
    ap.add_argument("--max-rmse-mm", type=float, help="claim: position RMSE at most this")
    ap.add_argument("--max-mm", type=float, help="claim: largest position error at most this")
    ap.add_argument("--json", help="also write the figures here")
    a = ap.parse_args()

    seq = os.path.join(a.dataset, "sequences", a.split + ".txt")
    try:
        with open(seq) as f:
            names = [line.strip() for line in f if line.strip() and not line.startswith("#")]
        with open(os.path.join(a.dataset, "poses.csv"), newline="") as f:
            truth = {r["image"]: (float(r["x"]), float(r["y"]), float(r["theta"]))
                     for r in csv.DictReader(f)}
        with open(a.poses, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as e:
        fail(str(e))
    if not rows:
        fail(a.poses + ": no keyframes")
    pos, head = [], []
    for line, r in enumerate(rows, start=2):
        if int(r["id"]) < a.first_id:
            continue
        try:
            stamp = float(r["stamp"])
            has_pose = r["has_pose"] == "1"
            x, y, th = float(r["x"]), float(r["y"]), float(r["theta"])
        except (KeyError, TypeError, ValueError) as e:
            fail(f"{a.poses}:{line}: not a map-info --poses row ({e})")
        if not has_pose:
            fail(f"{a.poses}:{line}: keyframe {r['id']} has no pose")
        i = round((stamp - a.start) * a.rate)
        if abs((stamp - a.start) * a.rate - i) > 1e-3 or not 0 <= i < len(names):
            fail(f"{a.poses}:{line}: stamp {stamp:.9f} is no {a.split} image's "
                 f"(--start {a.start}, --rate {a.rate}, {len(names)} images)")
        tx, ty, tth = truth[names[i]]
        pos.append(1000.0 * math.hypot(x - tx, y - ty))
        head.append(abs(math.degrees(math.atan2(math.sin(th - tth), math.cos(th - tth)))))
    if not pos:
        fail(a.poses + ": no keyframe from id %d on" % a.first_id)
    rmse = math.sqrt(sum(e * e for e in pos) / len(pos))
    figures = {"keyframes": len(pos), "rmse_mm": rmse, "max_mm": max(pos),
               "heading_rmse_deg": math.sqrt(sum(e * e for e in head) / len(head)),
               "heading_max_deg": max(head)}
    print("%s: %d keyframes, position error RMSE %.3f mm, max %.3f mm; heading RMSE %.4f deg, "
          "max %.4f deg" % (a.label, len(pos), rmse, max(pos), figures["heading_rmse_deg"],
                            figures["heading_max_deg"]))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(figures, f, indent=1)
    if a.max_rmse_mm is None and a.max_mm is None:
        return 0
    ok = (a.max_rmse_mm is None or rmse <= a.max_rmse_mm) and (a.max_mm is None or
                                                             max(pos) <= a.max_mm)
    bounds = []
    if a.max_rmse_mm is not None:
        bounds.append("RMSE <= %g mm" % a.max_rmse_mm)
    if a.max_mm is not None:
        bounds.append("max <= %g mm" % a.max_mm)
    print("%s: %s (%s)" % (a.label, "PASS" if ok else "FAIL", ", ".join(bounds)))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
