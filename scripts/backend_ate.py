#!/usr/bin/env python3
"""Absolute trajectory error of the pose-graph backend on a synthetic drive (issue 15, part 5).

Reads the drive's ground truth (DATASET/poses.csv, sequences/drive.txt), its odometry
(DATASET/drive_odometry.csv: the camera footprint by wheel odometry) and any number of
trajectories written by pose_graph_backend (~save_trajectory: its camera_* columns), and prints
the position error of the camera footprint at every drive image: RMSE and maximum, in mm.
No alignment is fitted: the map and odometry frames both start at the first true pose, so
the errors are those a robot would see.

With --max-rmse-mm and/or --min-improvement it also checks a claim and prints a verdict line:
every --run's ATE RMSE below MAX_RMSE_MM, and odometry alone's at least MIN_IMPROVEMENT times
every --run's; it exits 1 when the claim fails (after writing the table and the plot).

Usage: backend_ate.py DATASET --start 1000 --rate 10 [--plot out.png] [--markdown out.md]
                      [--max-rmse-mm 1.0] [--min-improvement 10] --run LABEL=trajectory.csv ...
"""
import argparse
import csv
import math
import os
import sys


def read_poses(path):
    with open(path, newline="") as f:
        return {r["image"]: (float(r["x"]), float(r["y"]), float(r["theta"]))
                for r in csv.DictReader(f)}


def read_trajectory(path, start, rate, n):
    """The camera_* columns of a backend CSV, by drive image index."""
    out = [None] * n
    with open(path, newline="") as f:
        for line, r in enumerate(csv.DictReader(f), start=2):
            try:
                stamp = float(r["stamp"])
                pose = (float(r["camera_x"]), float(r["camera_y"]), float(r["camera_theta"]))
            except (KeyError, TypeError, ValueError) as e:
                sys.exit(f"{path}:{line}: not a pose_graph_backend trajectory row ({e})")
            i = round((stamp - start) * rate)
            if abs((stamp - start) * rate - i) > 1e-3 or not 0 <= i < n:
                sys.exit(f"{path}:{line}: stamp {stamp:.9f} is no drive image's "
                         f"(--start {start}, --rate {rate}, {n} images)")
            out[i] = pose
    missing = sum(p is None for p in out)
    if missing:
        sys.exit(f"{path}: {missing} of {n} drive images have no pose")
    if any(math.isnan(c) for p in out for c in p):
        sys.exit(f"{path}: camera columns are NaN (the backend never learnt the camera mounting)")
    return out


def errors(truth, est):
    return [math.hypot(e[0] - t[0], e[1] - t[1]) for t, e in zip(truth, est)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("--run", action="append", default=[], dest="trajectories",
                    help="LABEL=backend_trajectory.csv (repeatable)")
    ap.add_argument("--start", type=float, default=1000.0, help="stamp of the first image, s")
    ap.add_argument("--rate", type=float, default=10.0, help="images per second of the bag")
    ap.add_argument("--plot", help="PNG of the trajectories over the ground truth")
    ap.add_argument("--markdown", help="also write the table here")
    ap.add_argument("--max-rmse-mm", type=float,
                    help="claim: every --run's ATE RMSE is below this (mm)")
    ap.add_argument("--min-improvement", type=float,
                    help="claim: odometry alone's ATE RMSE is at least this many times every "
                    "--run's")
    a = ap.parse_args()
    checking = a.max_rmse_mm is not None or a.min_improvement is not None
    if checking and not a.trajectories:
        sys.exit("--max-rmse-mm and --min-improvement need at least one --run")

    with open(os.path.join(a.dataset, "sequences", "drive.txt")) as f:
        names = [line.strip() for line in f if line.strip() and not line.startswith("#")]
    gt_all = read_poses(os.path.join(a.dataset, "poses.csv"))
    odo_all = read_poses(os.path.join(a.dataset, "drive_odometry.csv"))
    truth = [gt_all[n] for n in names]
    runs = [("odometry alone", [odo_all[n] for n in names])]
    for spec in a.trajectories:
        label, sep, path = spec.partition("=")
        if not sep:
            sys.exit(f"trajectory '{spec}' must be LABEL=path")
        runs.append((label, read_trajectory(path, a.start, a.rate, len(names))))

    length = sum(math.hypot(b[0] - a_[0], b[1] - a_[1]) for a_, b in zip(truth, truth[1:]))
    lines = [f"Drive: {length:.1f} m, {len(names)} images; camera-footprint position error, "
             "no alignment fitted", "",
             "| trajectory | ATE RMSE (mm) | ATE max (mm) | final error (mm) |",
             "|---|---:|---:|---:|"]
    rmses = []
    for label, est in runs:
        e = errors(truth, est)
        rmse = math.sqrt(sum(x * x for x in e) / len(e))
        rmses.append(rmse)
        lines.append(f"| {label} | {1e3 * rmse:.2f} | {1e3 * max(e):.2f} | {1e3 * e[-1]:.2f} |")
    print("\n".join(lines))
    failures = []
    if checking:
        odo_mm = 1e3 * rmses[0]
        for (label, _), rmse in zip(runs[1:], rmses[1:]):
            mm = 1e3 * rmse
            if a.max_rmse_mm is not None and not mm < a.max_rmse_mm:
                failures.append(f"{label}: ATE RMSE {mm:.2f} mm, not below {a.max_rmse_mm:g} mm")
            if a.min_improvement is not None and not odo_mm >= a.min_improvement * mm:
                failures.append(f"{label}: odometry alone's ATE RMSE {odo_mm:.2f} mm is not "
                                f"{a.min_improvement:g} times its {mm:.2f} mm")
        claim = " and ".join(
            ([f"every backend's ATE RMSE below {a.max_rmse_mm:g} mm"]
             if a.max_rmse_mm is not None else []) +
            ([f"odometry alone's at least {a.min_improvement:g} times it"]
             if a.min_improvement is not None else []))
        if failures:
            print(f"verdict: FAIL (claim: {claim}): " + "; ".join(failures))
        else:
            print(f"verdict: PASS (claim: {claim})")
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write("\n".join(lines) + "\n")

    if a.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 6),
                                      gridspec_kw={"width_ratios": [1.3, 1]})
        ax.plot([p[0] for p in truth], [p[1] for p in truth], "k-", lw=2.5, label="ground truth")
        dist = [0.0]
        for p, q in zip(truth, truth[1:]):
            dist.append(dist[-1] + math.hypot(q[0] - p[0], q[1] - p[1]))
        styles = ["--", "-", "-", "-", "-"]
        for (label, est), style in zip(runs, styles):
            ax.plot([p[0] for p in est], [p[1] for p in est], style, lw=1, label=label)
            ax2.plot(dist, [1e3 * x for x in errors(truth, est)], style, lw=1, label=label)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title("Camera footprint over the ground truth")
        ax.legend(loc="best", fontsize=8)
        ax2.set_yscale("log")
        ax2.set_xlabel("distance driven (m)")
        ax2.set_ylabel("position error (mm)")
        ax2.set_title("Error along the drive")
        ax2.grid(True, which="both", alpha=0.3)
        ax2.legend(loc="best", fontsize=8)
        fig.tight_layout()
        fig.savefig(a.plot, dpi=110)
        print(f"plot: {a.plot}")
    if failures:
        sys.exit(1)


if __name__ == "__main__":
    main()
