#!/usr/bin/env python3
"""Scores the localizer's pose fixes against a bag's ground truth.

Reads the ground truth (geometry_msgs/PoseStamped, the camera footprint, written by
`gtbow_images_to_bag`) and the image stamps from BAG, listens to FIX_TOPIC
(PoseWithCovarianceStamped) until the node has processed every image of the bag (or TIMEOUT
seconds pass without a new fix), and prints the success rate at the protocol's tolerance
(4.8 mm, 1.5 degrees), and the RMSE of the position error of every fix published.
Exit code 0 when at least MIN_RATE of the images were localized (and, with --max-rmse-mm, that
RMSE is at most MAX_RMSE_MM).

The ground truth is the camera footprint: score /localizer/camera_pose when the camera is not
straight above base_frame (~pose is the base's pose).

Usage: fix_accuracy.py BAG [--fix-topic /localizer/pose] [--min-rate 0.9] [--max-rmse-mm 2]
                       [--timeout 20]
"""
import argparse
import math
import sys
import threading
import time

import rosbag
import rospy
from geometry_msgs.msg import PoseWithCovarianceStamped


def yaw(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bag")
    ap.add_argument("--fix-topic", default="/localizer/pose")
    ap.add_argument("--truth-topic", default="/ground_truth/pose")
    ap.add_argument("--min-rate", type=float, default=0.9)
    ap.add_argument("--max-rmse-mm", type=float, default=None,
                    help="also require the RMSE of every fix's position error to be at most this")
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--ready-file", default="", help="touched once subscribed")
    args = ap.parse_args(rospy.myargv()[1:])

    truth = {}
    with rosbag.Bag(args.bag) as bag:
        for _, msg, _ in bag.read_messages(topics=[args.truth_topic]):
            truth[msg.header.stamp.to_nsec()] = (msg.pose.position.x, msg.pose.position.y,
                                                 yaw(msg.pose.orientation))
    if not truth:
        print("fix_accuracy: no ground truth on %s in %s" % (args.truth_topic, args.bag))
        return 2

    fixes = {}
    lock = threading.Lock()
    last = [time.time()]

    def on_fix(msg):
        p = msg.pose.pose
        with lock:
            fixes[msg.header.stamp.to_nsec()] = (p.position.x, p.position.y, yaw(p.orientation))
            last[0] = time.time()

    rospy.init_node("fix_accuracy", anonymous=True, disable_signals=True)
    rospy.Subscriber(args.fix_topic, PoseWithCovarianceStamped, on_fix, queue_size=1000)
    if args.ready_file:
        open(args.ready_file, "w").close()
    start = time.time()
    while not rospy.is_shutdown():
        time.sleep(0.2)
        with lock:
            if len(fixes) >= len(truth):
                break
            idle = time.time() - last[0]
        if time.time() - start > 5 and idle > args.timeout:
            break

    good, errors = 0, []
    with lock:
        for stamp, (x, y, th) in truth.items():
            if stamp not in fixes:
                continue
            fx, fy, fth = fixes[stamp]
            pos_mm = 1000.0 * math.hypot(fx - x, fy - y)
            head_deg = abs(math.degrees(math.atan2(math.sin(fth - th), math.cos(fth - th))))
            errors.append(pos_mm)
            good += pos_mm <= 4.8 and head_deg <= 1.5
    rate = good / len(truth)
    errors.sort()
    median = errors[len(errors) // 2] if errors else float("nan")
    rmse = math.sqrt(sum(e * e for e in errors) / len(errors)) if errors else float("nan")
    print("localization: %d of %d images localized within 4.8 mm and 1.5 deg (%.1f%%); "
          "%d fixes, median position error %.2f mm, RMSE of all fixes %.2f mm"
          % (good, len(truth), 100 * rate, len(fixes), median, rmse))
    ok = rate >= args.min_rate and (args.max_rmse_mm is None or rmse <= args.max_rmse_mm)
    if args.max_rmse_mm is not None:
        print("localization: %s (at least %.0f%% localized, RMSE <= %g mm)"
              % ("PASS" if ok else "FAIL", 100 * args.min_rate, args.max_rmse_mm))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
