#!/usr/bin/python3
"""Section "keypoints" of docs/RESULTS.md (make benchmark-keypoints, issue 17): verification
against the map's quantised keypoints (what the node stores) beside verification against the
exact ones (`gtbow eval --exact-keypoints`), both on the real floor photographs with the same
vocabularies, and the claims checked (scripts/targets.py: KEYPOINTS).

    write_keypoint_results.py [--strict] DOCS_DIR STORED_EVAL_DIR EXACT_EVAL_DIR
    write_keypoint_results.py --check [--strict] STORED_EVAL_DIR EXACT_EVAL_DIR

Each EVAL_DIR holds a gtbow eval run's results.json and verifications.csv. A verification is
the pair (preset, query, rank, map image); the two runs' verified poses are joined on it and
compared: how many both runs verify, how many only one, how many are identical (to the printed
micrometre and microradian), and the largest move of a pose between the runs.

Checked, for high_accuracy and fast: the same number of queries localized on every split, no
wrong verified pose either way, no pose verified both ways moved by more than 0.1 mm (exit 1
otherwise). Both runs must hold the ten surfaces, days 0 and 180 and the three presets of
scripts/benchmark_keypoints.sh (exit 2 otherwise).
"""
import csv
import math
import os
import statistics

import targets as T
from report_check import Check, load_json, parser, run, table
from results_section import splice


def verifications(chk, path):
    """{(preset, query, rank, image): (x, y, theta, wrong, split, error_mm)}"""
    out = {}
    try:
        with open(path) as f:
            for r in csv.DictReader(f):
                out[(r["preset"], r["query"], r["rank"], r["image"])] = (
                    float(r["x"]), float(r["y"]), float(r["theta"]), r["wrong"] == "1", r["split"],
                    float(r["error_mm"]))
    except OSError as e:
        chk.require(False, "%s (%s)" % (path, e))
    return out


def angle(a):
    return math.atan2(math.sin(a), math.cos(a))


def check_inputs(chk, res, which):
    by = {p["name"]: p for p in res["presets"]}
    for name in T.KEYPOINTS_EXPECT["presets"]:
        if not chk.need(name in by, "%s: the preset %s" % (which, name)):
            continue
        splits = [s for s in by[name]["splits"] if s["queries"] > 0]
        days = {s["day"] for s in splits}
        for d in T.KEYPOINTS_EXPECT["days"]:
            chk.need(d in days, "%s, %s: query splits of day %d" % (which, name, d))
        chk.need(len(splits) == T.KEYPOINTS_EXPECT["surfaces"] * len(T.KEYPOINTS_EXPECT["days"]),
                 "%s, %s: %d query splits (%d surfaces x %d days), has %d" % (
                     which, name, T.KEYPOINTS_EXPECT["surfaces"] * len(T.KEYPOINTS_EXPECT["days"]),
                     T.KEYPOINTS_EXPECT["surfaces"], len(T.KEYPOINTS_EXPECT["days"]), len(splits)))
    return by


def compare(chk, stored, exact, vs, ve):
    """Rows of the per-preset table and of the targets."""
    table_rows, target_rows = [], []
    overall = 0.0
    for name in T.KEYPOINTS_EXPECT["presets"]:
        a, b = stored[name], exact[name]
        sa = {s["name"]: s for s in a["splits"]}
        sb = {s["name"]: s for s in b["splits"]}
        chk.need(set(sa) == set(sb), "%s: the same query splits in both runs" % name)
        loc_a = sum(s["localization"]["correct"] for s in sa.values())
        loc_b = sum(s["localization"]["correct"] for s in sb.values())
        differ = sum(abs(sa[k]["localization"]["correct"] - sb[k]["localization"]["correct"])
                     for k in sa if k in sb)
        splits_differ = sum(1 for k in sa if k in sb and
                            sa[k]["localization"]["correct"] != sb[k]["localization"]["correct"])
        ver_a = sum(s["backend"]["verified_poses"] for s in sa.values())
        ver_b = sum(s["backend"]["verified_poses"] for s in sb.values())
        wr_a = sum(s["backend"]["wrong_verified_poses"] for s in sa.values())
        wr_b = sum(s["backend"]["wrong_verified_poses"] for s in sb.values())
        ka = {k for k in vs if k[0] == name}
        kb = {k for k in ve if k[0] == name}
        med_a = statistics.median(vs[k][5] for k in ka) if ka else float("nan")
        med_b = statistics.median(ve[k][5] for k in kb) if kb else float("nan")
        both = ka & kb
        chk.need(len(ka) == ver_a and len(kb) == ver_b,
                 "%s: verifications.csv rows for every verified pose (%d and %d rows, %d and %d poses)" % (
                     name, len(ka), len(kb), ver_a, ver_b))
        same, shift, turn = 0, 0.0, 0.0
        for k in both:
            p, q = vs[k], ve[k]
            d = 1000.0 * math.hypot(p[0] - q[0], p[1] - q[1])
            shift = max(shift, d)
            turn = max(turn, abs(angle(p[2] - q[2])) * 180.0 / math.pi)
            same += 1 if p[:3] == q[:3] else 0
        overall = max(overall, shift)
        n_splits = len(sa)
        table_rows.append("| `%s` | %s / %s | %d / %d | %d / %d | %d of %d | %.4f / %.4f | %s | %s | %s | %.4f mm, %.4f deg |" % (
            name, "{:,}".format(ver_a), "{:,}".format(ver_b), wr_a, wr_b, loc_a, loc_b,
            n_splits - splits_differ, n_splits, med_a, med_b, "{:,}".format(len(both)),
            "{:,}".format(len(ka - kb) + len(kb - ka)), "{:,}".format(same), shift, turn))
        if name in T.KEYPOINTS_PRESETS:
            target_rows.append(chk.target(T.KEYPOINTS["same_localization"], differ, name,
                                          "%d queries differ (%d of %d splits)" % (differ, splits_differ, n_splits)))
            target_rows.append(chk.target(T.KEYPOINTS["zero_wrong"], max(wr_a, wr_b), name,
                                          "%d / %d" % (wr_a, wr_b)))
            target_rows.append(chk.target(T.KEYPOINTS["max_shift_mm"], shift, name,
                                          "%.4f mm (%s poses)" % (shift, "{:,}".format(len(both)))))
    return table_rows, target_rows, overall


def main():
    p = parser(__doc__)
    p.add_argument("inputs", nargs="+", help="[DOCS_DIR] STORED_EVAL_DIR EXACT_EVAL_DIR")
    a = p.parse_args()
    if len(a.inputs) != (2 if a.check else 3):
        p.error("DOCS_DIR STORED_EVAL_DIR EXACT_EVAL_DIR (or --check STORED_EVAL_DIR EXACT_EVAL_DIR)")
    docs = None if a.check else a.inputs[0]
    stored_dir, exact_dir = a.inputs[-2:]
    chk = Check("benchmark-keypoints", a.strict)

    def go():
        rs = load_json(chk, os.path.join(stored_dir, "results.json"))
        re_ = load_json(chk, os.path.join(exact_dir, "results.json"))
        stored = check_inputs(chk, rs, "quantised")
        exact = check_inputs(chk, re_, "exact")
        if chk.missing:
            return
        vs = verifications(chk, os.path.join(stored_dir, "verifications.csv"))
        ve = verifications(chk, os.path.join(exact_dir, "verifications.csv"))
        table_rows, target_rows, overall = compare(chk, stored, exact, vs, ve)
        print("largest move of a pose verified both ways, every preset: %.4f mm" % overall)
        if docs is None or chk.missing:
            return
        queries = sum(s["queries"] for s in stored["high_accuracy"]["splits"])
        lines = ["Generated by `make benchmark-keypoints` (scripts/benchmark_keypoints.sh): `gtbow eval` on the real "
                 "floor photographs (make benchmark-real's data: %d surfaces, days %s, %d queries; V = 20,000, "
                 "the same cached vocabularies) twice: verifying against the map's keypoints as the node stores "
                 "them (quantised: x and y in steps of max(width, height) / 65535 px, orientation in 4096 "
                 "steps, size in 1/16 px) and with `--exact-keypoints` against the unquantised ones. Each cell "
                 "is quantised / exact. A verification is a (query, rank, map image) pair; \"both\" are those "
                 "both runs verify, \"one\" those only one run verifies, \"identical\" those with the same pose "
                 "to the printed micrometre and microradian; \"largest move\" is over the poses both verify."
                 % (T.KEYPOINTS_EXPECT["surfaces"], " and ".join(str(d) for d in T.KEYPOINTS_EXPECT["days"]), queries), "",
                 "| preset | verified poses | wrong | localized | splits with the same localization | "
                 "median position error of the verified poses (mm) | both | one | identical | largest move |",
                 "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"] + table_rows
        lines += ["", "Largest move of a pose verified both ways, every preset: %.4f mm." % overall, ""]
        lines += table(target_rows)
        print("wrote %s" % splice(docs, "keypoints", "\n".join(lines)))

    run(chk, go)


if __name__ == "__main__":
    main()
