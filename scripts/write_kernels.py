#!/usr/bin/python3
"""Puts a make benchmark-kernels run into docs/RESULTS.md and checks its targets
(scripts/targets.py, KERNELS).

    write_kernels.py [--check] [--strict] OUT_DIR [DOCS_DIR]

Reads OUT_DIR/eval_timing/results.json (gtbow eval --timing-kernels: every kernel on each
timed query), OUT_DIR/train_<kernel>.txt (gtbow train-vocab), OUT_DIR/cpu.txt (the CPU the
run was on; else this machine's) and the rankings and poses that
the evals under each GTBOW_SIMD dumped, and replaces the part of DOCS_DIR/RESULTS.md between
<!-- kernels:begin --> and <!-- kernels:end -->. A kernel the CPU lacks runs as the next one
down; the table keeps one row per kernel that ran. Exits 1 when a
claim is missed or the answers of two kernels differ, 2 when an input is absent.
"""
import glob
import os
import re
import statistics

import targets as T
from report_check import Check, fmt, load_json, parser, run, table

STAGES = [("feature_extraction", "extraction"), ("bow_transform", "BoW transform"),
          ("database_query", "query"), ("pose_estimation", "pose"), ("end_to_end", "end to end")]


def main():
    p = parser(__doc__)
    p.add_argument("out")
    p.add_argument("docs", nargs="?")
    a = p.parse_args()
    if not a.check and not a.docs:
        p.error("DOCS_DIR is needed unless --check")
    chk = Check("kernels", a.strict)

    def go():
        res = load_json(chk, os.path.join(a.out, "eval_timing", "results.json"))
        by = {pr["name"]: pr for pr in res["presets"]}
        med = {}  # (kernel, preset, stage) -> median ms
        order = []
        queries = 0
        extra = [n for n in T.KERNELS_SEARCH if n not in T.KERNELS_EXPECT["presets"]]
        for name in T.KERNELS_EXPECT["presets"] + extra:
            if name in extra and name not in by:
                continue  # the search's effort: informative, left out when absent
            if not chk.need(name in by, "the preset %s" % name):
                continue
            timing = by[name]["timing"]
            queries = timing["queries"]
            for kt in timing["by_kernel"]:
                k = kt["hamming"]
                if kt["requested"] != k:
                    continue  # the CPU lacks it: it ran as another
                if k not in order:
                    order.append(k)
                for stage, _ in STAGES:
                    med[(k, name, stage)] = kt[stage]["median_ms"]
        for k in T.KERNELS_EXPECT["kernels"]:
            chk.need(os.path.exists(os.path.join(a.out, "eval_%s" % k, "results.json")),
                     "the answers under GTBOW_SIMD=%s" % k)
        if chk.missing:
            return
        order.sort(key=lambda k: -T.KERNELS_EXPECT["kernels"].index(k))
        train = {}
        for k in order + ["avx2_no_bound"]:
            path = os.path.join(a.out, "train_%s.txt" % k)
            if chk.need(os.path.exists(path), path):
                mt = re.search(r"in ([0-9.]+) s", open(path).read())
                train[k] = float(mt.group(1)) if mt else None
        # Every kernel's answers are the portable kernel's.
        same = True
        for f in glob.glob(os.path.join(a.out, "*_portable.*.csv")):
            for k in order:
                other = f.replace("_portable.", "_%s." % k)
                if not os.path.exists(other) or open(other, "rb").read() != open(f, "rb").read():
                    same = False
        chk.claim(same and glob.glob(os.path.join(a.out, "*_portable.*.csv")),
                  "every kernel's rankings and poses equal the portable kernel's")
        rows = []
        ha = "high_accuracy"
        if "avx512" in order:
            for k, key in (("avx2", "avx2_ratio"), ("popcnt", "popcnt_ratio")):
                if k in order:
                    r = med[(k, ha, "bow_transform")] / med[("avx512", ha, "bow_transform")]
                    rows.append(chk.target(T.KERNELS[key], r, "", "%.2f vs %.2f ms (x%.2f)" % (
                        med[(k, ha, "bow_transform")], med[("avx512", ha, "bow_transform")], r)))
        cpu = run_cpu(a.out)
        if "avx2" in order:
            avx2 = med[("avx2", ha, "bow_transform")]
            if T.AUTHORS_TRANSFORM_CPU in cpu:
                rows.append(chk.target(T.KERNELS["avx2_vs_authors"], avx2, "", "%.2f ms (%.1fx faster)"
                                       % (avx2, T.AUTHORS_TRANSFORM_MS / avx2)))
            else:  # the authors' figure is another machine's: no verdict here
                t = T.KERNELS["avx2_vs_authors"]
                rows.append((t.what, "%s %g ms" % (t.op, t.bound), "%.2f ms" % avx2,
                             "not checked: the authors' code was timed on an %s; this run's CPU: %s"
                             % (T.AUTHORS_TRANSFORM_CPU, cpu)))
            rows.append(chk.target(T.KERNELS["train_avx2_s"], train.get("avx2"), "",
                                   "%s s" % train.get("avx2")))
        if a.check or chk.missing:
            return
        ds = res["dataset"]
        lines = ["## Kernels: the timings on every robot computer", "",
                 "Generated by `make benchmark-kernels` (scripts/benchmark_kernels.sh): the real-floor "
                 "dataset of `make benchmark-real` (a database of %d images of %d x %d), V = 20,000 trained on 240 "
                 "of its train images, one thread for every timing, each kernel forced with "
                 "`SetSimdLimit` (`gtbow eval --timing-kernels`) on one machine (CPU: %s). Each of "
                 "%d random queries runs through every stage under each kernel in turn, the "
                 "order rotating, so that the machine's own changes of speed fall on every "
                 "kernel alike; medians. Feature extraction (OpenCV) is the same code under "
                 "every kernel. Every kernel's vocabulary is "
                 "byte-identical, and its rankings and poses are identical to the portable kernel's "
                 "(checked by the script)." % (
                     res["presets"][0]["database_images"], ds["image_width"],
                     ds["image_height"], cpu, queries), ""]
        lines += table(rows)
        lines += ["", "| kernel | preset | " + " | ".join(s for _, s in STAGES) + " (ms) | rate |",
                  "| --- | --- | " + " | ".join("---" for _ in STAGES) + " | --- |"]
        for k in order:
            for name in T.KERNELS_EXPECT["presets"]:
                vals = [med[(k, name, st)] for st, _ in STAGES]
                lines.append("| %s | %s | %s | %.0f Hz |" % (
                    k, name, " | ".join("%.2f" % v for v in vals), 1000.0 / med[(k, name, "end_to_end")]))
        lines += search_effort(by, order, med)
        lines += ["", "Vocabulary training (gtbow train-vocab, V = 20,000, 60,000 descriptors, one "
                  "thread, extraction included):", "", "| kernel | seconds |", "| --- | --- |"]
        for k in order + ["avx2_no_bound"]:
            label = "avx2, k-means without the triangle bound" if k == "avx2_no_bound" else k
            lines.append("| %s | %s |" % (label, "%.1f" % train[k] if train.get(k) else "-"))
        from results_section import splice
        print("wrote %s" % splice(a.docs, "kernels", "\n".join(lines)))

    run(chk, go)


def search_effort(by, order, med):
    """The table of the word search's effort: each preset of T.KERNELS_SEARCH (the same preset
    probing fewer lists) with its accuracy and its transform under every kernel."""
    rows = [n for n in T.KERNELS_SEARCH if n in by and all((k, n, "bow_transform") in med for k in order)]
    if not rows:
        return []
    def by_day(pr):
        per_day = {}
        for sp in pr.get("splits", []):
            if sp["name"].startswith("query"):
                per_day.setdefault(sp["day"], []).append(sp)
        return per_day

    days = sorted(by_day(by[rows[0]]))
    ratios = order[1:]  # against the widest kernel that ran (none when only one ran)
    lines = ["", "The word search's effort: the presets above probing fewer of the word lists per "
             "descriptor (`vocabulary.nprobe`, of the %s; config/ablation/search/), in the "
             "same timing run: mAP@1000 and the share of queries localized, each averaged over the "
             "surfaces, and the wrong verified poses of all days." % T.KERNELS_LISTS, "",
             "| preset | lists probed | mAP day %s | localized day %s | wrong | BoW transform %s (ms) |"
             % (" / ".join(map(str, days)), " / ".join(map(str, days)), " / ".join(order)) +
             "".join(" %s / %s |" % (k, order[0]) for k in ratios),
             "| --- | --- | --- | --- | --- | --- |" + " --- |" * len(ratios)]
    def mean(xs):
        return sum(xs) / len(xs) if xs else 0.0

    for n in rows:
        pr = by[n]
        per_day = by_day(pr)
        maps = " / ".join("%.3f" % mean([sp["map_at_1000"] for sp in per_day.get(d, [])])
                          for d in days)
        loc = " / ".join("%.1f%%" % (100 * mean([sp["localization"]["success_rate"]
                                                 for sp in per_day.get(d, [])])) for d in days)
        wrong = sum(sp["backend"]["wrong_verified_poses"] for d in days for sp in per_day.get(d, []))
        t = [med[(k, n, "bow_transform")] for k in order]
        # The key itself, not train_nprobe.
        nprobe = re.search(r"(?m)^\s*nprobe:\s*([0-9]+)", pr.get("configuration") or "")
        lines.append("| %s | %s | %s | %s | %d | %s |" % (
            n, nprobe.group(1) if nprobe else "-", maps, loc, wrong, " / ".join("%.2f" % v for v in t)) +
            "".join(" x%.2f |" % (v / t[0]) for v in t[1:]))
    return lines


def run_cpu(out):
    """The CPU of the run: OUT_DIR/cpu.txt (benchmark_kernels.sh), else this machine's."""
    try:
        with open(os.path.join(out, "cpu.txt")) as f:
            name = f.read().strip()
        if name:
            return name
    except OSError:
        pass
    return cpu_name()


def cpu_name():
    """This machine's CPU as benchmark_kernels.sh writes it: "NAME (family F, model M)"."""
    fields = {}
    try:
        for line in open("/proc/cpuinfo"):
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    if "model name" not in fields:
        return "unknown"
    if "cpu family" in fields and "model" in fields:
        return "%s (family %s, model %s)" % (fields["model name"], fields["cpu family"],
                                             fields["model"])
    return fields["model name"]


if __name__ == "__main__":
    main()
