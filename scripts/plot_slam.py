#!/usr/bin/python3
"""Plot a gtbow slam run: the trajectory (odometry alone, optimised, ground truth) with the
keyframes and the loop closures, and the position error along the drive before and after.
Usage: plot_slam.py OUT_DIR   (reads trajectory.csv, keyframes.csv, closures.csv; writes slam.png)"""
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = sys.argv[1]
    traj = rows(os.path.join(out, "trajectory.csv"))
    kfs = rows(os.path.join(out, "keyframes.csv"))
    closures = rows(os.path.join(out, "closures.csv"))
    truth = bool(traj) and traj[0]["true_x"] != ""
    fig, (ax, ax_e) = plt.subplots(1, 2, figsize=(15, 6), gridspec_kw={"width_ratios": [1.2, 1]})
    f = lambda key: [float(r[key]) for r in traj]  # noqa: E731
    ax.plot(f("odom_x"), f("odom_y"), color="tab:red", lw=0.8, label="odometry alone")
    if truth:
        ax.plot(f("true_x"), f("true_y"), color="0.6", lw=2.5, label="ground truth")
    ax.plot(f("x"), f("y"), color="tab:blue", lw=0.8, label="optimised")
    ax.plot([float(k["x"]) for k in kfs], [float(k["y"]) for k in kfs], ".", color="tab:blue",
            ms=4, label="keyframes (map)")
    by_image = {r["image"]: r for r in traj}
    first = True
    for c in closures:
        q, m = by_image[c["query_image"]], by_image[c["match_image"]]
        wrong = c.get("correct") == "0"
        ax.plot([float(q["x"]), float(m["x"])], [float(q["y"]), float(m["y"])],
                color="tab:red" if wrong else "tab:green", lw=0.6, alpha=0.7,
                label=("loop closures" if first else None))
        first = False
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("%d images, %d keyframes, %d loop closures" % (len(traj), len(kfs), len(closures)))
    if truth:
        dist, d = [], 0.0
        for i, r in enumerate(traj):
            if i:
                d += math.hypot(float(r["true_x"]) - float(traj[i - 1]["true_x"]),
                                float(r["true_y"]) - float(traj[i - 1]["true_y"]))
            dist.append(d)
        err = lambda kx, ky: [1e3 * math.hypot(float(r[kx]) - float(r["true_x"]),  # noqa: E731
                                               float(r[ky]) - float(r["true_y"])) for r in traj]
        ax_e.plot(dist, err("odom_x", "odom_y"), color="tab:red", label="odometry alone")
        ax_e.plot(dist, err("x", "y"), color="tab:blue", label="optimised")
        ax_e.set_yscale("log")
        ax_e.set_xlabel("distance driven (m)")
        ax_e.set_ylabel("position error (mm)")
        ax_e.legend(loc="best")
        ax_e.grid(True, which="both", alpha=0.3)
    else:
        ax_e.axis("off")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "slam.png"), dpi=110)


if __name__ == "__main__":
    main()
