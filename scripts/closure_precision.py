#!/usr/bin/env python3
"""Precision and latency of the localizer's published loop closures on a synthetic drive.

Reads bags of /localizer/loop_closures recorded during a replay of the drive
(scripts/backend_demo.sh: closures_<preset>_n<N>.bag) and the drive's ground truth
(DATASET/poses.csv, sequences/drive.txt). Image stamps are --start + index / --rate, as
gtbow_images_to_bag writes them (and scripts/backend_ate.py reads them back).

Precision: each closure's match_from_query (the query camera in the match camera's optical
frame, which sees the floor mirrored) is taken back to the floor frame as (x, -y, -theta) and
composed with the match image's true footprint, exactly as test/ros/rostest_util.h (Compose)
and pose_graph_backend (ToBaseClosure) do; the result is compared with the query image's true
footprint. A closure is wrong beyond 4.8 mm or 1.5 degrees.

Latency (--latency RUN=REFERENCE, e.g. the N=3 run against the N=1 run of the same preset):
the reference's closures are grouped into revisit episodes, runs of consecutive query images
with a closure. For each episode, the delay from its first reference closure to the run's first
closure within the episode, in images and seconds; episodes where the run publishes nothing
are counted as missed.

Usage: closure_precision.py DATASET --start 1000 --rate 20
           --run "high_accuracy N=1=closures_high_accuracy_n1.bag" ...
           [--latency "high_accuracy N=3=high_accuracy N=1"] [--markdown out.md]
(--run splits at the last '=', so labels may contain '=' but paths may not; --latency splits
at the '=' that leaves two --run labels.)
"""
import argparse
import csv
import math
import os
import statistics
import sys

TOPIC = "/localizer/loop_closures"
MAX_POSITION_MM = 4.8
MAX_HEADING_DEG = 1.5


def compose(a, b):
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def read_poses(path):
    with open(path, newline="") as f:
        return {r["image"]: (float(r["x"]), float(r["y"]), float(r["theta"]))
                for r in csv.DictReader(f)}


def image_index(stamp, start, rate, n, where):
    """The drive image index of a stamp (rospy Time), exactly as the bag was written."""
    t = stamp.secs + stamp.nsecs * 1e-9
    f = (t - start) * rate
    i = round(f)
    if abs(f - i) > 1e-3 or not 0 <= i < n:
        sys.exit(f"{where}: stamp {t:.9f} is no drive image's (--start {start}, --rate {rate}, "
                 f"{n} images)")
    return i


def read_closures(path, start, rate, truth):
    """Closures of a bag: dicts with query/match image indices and the pose errors."""
    import rosbag  # python3-rosbag (Debian)
    out = []
    with rosbag.Bag(path) as bag:
        for _, m, _ in bag.read_messages(topics=[TOPIC]):
            where = f"{path}: closure {len(out)}"
            q = image_index(m.query_stamp, start, rate, len(truth), where + " query_stamp")
            k = image_index(m.match_stamp, start, rate, len(truth), where + " match_stamp")
            p = m.match_from_query
            # Optical frame -> the floor seen from above (rostest_util.h Compose).
            est = compose(truth[k], (p.x, -p.y, -p.theta))
            pos_mm = 1e3 * math.hypot(est[0] - truth[q][0], est[1] - truth[q][1])
            head_deg = abs(math.remainder(est[2] - truth[q][2], 2 * math.pi)) * 180 / math.pi
            out.append({"query": q, "match": k, "inliers": m.inliers, "status": m.status,
                        "pos_mm": pos_mm, "head_deg": head_deg,
                        "wrong": pos_mm > MAX_POSITION_MM or head_deg > MAX_HEADING_DEG})
    return out


def episodes_of(closures):
    """Runs of consecutive query images with a closure: [(first, last)] image indices."""
    qs = sorted({c["query"] for c in closures})
    eps = []
    for q in qs:
        if eps and q == eps[-1][1] + 1:
            eps[-1][1] = q
        else:
            eps.append([q, q])
    return [tuple(e) for e in eps]


def fmt(x, spec):
    return "-" if x is None else format(x, spec)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("--run", action="append", default=[], required=True,
                    help="LABEL=closures.bag (repeatable)")
    ap.add_argument("--latency", action="append", default=[],
                    help="RUN_LABEL=REFERENCE_LABEL: episodes from the reference (repeatable)")
    ap.add_argument("--start", type=float, default=1000.0, help="stamp of the first image, s")
    ap.add_argument("--rate", type=float, default=10.0, help="images per second of the bag")
    ap.add_argument("--markdown", help="also write the tables here")
    ap.add_argument("--list-wrong", action="store_true", help="print every wrong closure")
    a = ap.parse_args()

    with open(os.path.join(a.dataset, "sequences", "drive.txt")) as f:
        names = [line.strip() for line in f if line.strip() and not line.startswith("#")]
    gt_all = read_poses(os.path.join(a.dataset, "poses.csv"))
    truth = [gt_all[n] for n in names]

    runs = {}
    for spec in a.run:
        label, sep, path = spec.rpartition("=")
        if not sep or not label:
            sys.exit(f"--run '{spec}' must be LABEL=path")
        if not os.path.isfile(path):
            sys.exit(f"--run '{spec}': no such bag {path}")
        runs[label] = read_closures(path, a.start, a.rate, truth)

    lines = [f"Drive: {len(names)} images at {a.rate:g} Hz; a closure is wrong beyond "
             f"{MAX_POSITION_MM} mm or {MAX_HEADING_DEG} deg (match_from_query against the "
             "ground-truth relative pose of the two camera footprints)", "",
             "| run | closures published | wrong | precision | position error median / max (mm) "
             "| heading error max (deg) | query images with a closure |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    wrong_lines = []
    for label, cl in runs.items():
        n = len(cl)
        wrong = [c for c in cl if c["wrong"]]
        not_verified = sum(c["status"] != 0 for c in cl)
        if not_verified:
            print(f"warning: {label}: {not_verified} closures not VERIFIED", file=sys.stderr)
        prec = (n - len(wrong)) / n if n else None
        pos = [c["pos_mm"] for c in cl]
        lines.append(
            f"| {label} | {n} | {len(wrong)} | {fmt(None if prec is None else 100 * prec, '.2f')}"
            f"{'' if prec is None else ' %'} | "
            f"{fmt(statistics.median(pos) if pos else None, '.2f')} / "
            f"{fmt(max(pos) if pos else None, '.2f')} | "
            f"{fmt(max(c['head_deg'] for c in cl) if cl else None, '.3f')} | "
            f"{len({c['query'] for c in cl})} |")
        for c in wrong:
            wrong_lines.append(f"  {label}: query image {c['query']} -> match {c['match']}: "
                               f"{c['pos_mm']:.2f} mm, {c['head_deg']:.3f} deg, "
                               f"{c['inliers']} inliers")

    if a.latency:
        lines += ["", "Latency: revisit episodes = runs of consecutive query images with a closure "
                  "in the reference run; delay = first closure of the run in the episode minus the "
                  "episode's first reference closure", "",
                  "| run (reference) | episodes | with a closure | missed | delay median / max "
                  "(images) | delay median / max (s) | closures outside episodes |",
                  "|---|---:|---:|---:|---:|---:|---:|"]
    notes = []
    for spec in a.latency:
        pair = None
        for i, ch in enumerate(spec):
            if ch == "=" and spec[:i] in runs and spec[i + 1:] in runs:
                pair = (spec[:i], spec[i + 1:])
        if pair is None:
            sys.exit(f"--latency '{spec}': not RUN=REFERENCE of two --run labels")
        run, ref = pair
        eps = episodes_of(runs[ref])
        first_of = {}  # episode -> first query index of the run in it
        outside = 0
        for q in sorted({c["query"] for c in runs[run]}):
            # the episode containing q (episodes are sorted and disjoint)
            lo, hi = 0, len(eps)
            while lo < hi:
                mid = (lo + hi) // 2
                if eps[mid][1] < q:
                    lo = mid + 1
                else:
                    hi = mid
            if lo < len(eps) and eps[lo][0] <= q <= eps[lo][1]:
                first_of.setdefault(lo, q)
            else:
                outside += 1
        delays = [first_of[e] - eps[e][0] for e in sorted(first_of)]
        med = statistics.median(delays) if delays else None
        mx = max(delays) if delays else None
        lines.append(
            f"| {run} ({ref}) | {len(eps)} | {len(first_of)} | {len(eps) - len(first_of)} | "
            f"{fmt(med, 'g')} / {fmt(mx, 'g')} | "
            f"{fmt(None if med is None else med / a.rate, '.3f')} / "
            f"{fmt(None if mx is None else mx / a.rate, '.3f')} | {outside} |")
        lengths = [e[1] - e[0] + 1 for e in eps]
        if lengths:
            notes.append(f"- {ref}: {len(eps)} episodes of {min(lengths)} to {max(lengths)} "
                         f"images (median {statistics.median(lengths):g}); "
                         f"{sum(x < 3 for x in lengths)} shorter than 3 images")
    if notes:
        lines += [""] + notes

    print("\n".join(lines))
    if a.list_wrong and wrong_lines:
        print("\nwrong closures:\n" + "\n".join(wrong_lines))
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
