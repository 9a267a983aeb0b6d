#!/usr/bin/python3
"""Puts a `gtbow eval` run into docs/RESULTS.md.

    write_results.py EVAL_DIR DOCS_DIR

Copies EVAL_DIR's PNG plots to DOCS_DIR/results/, and replaces the part of DOCS_DIR/RESULTS.md
between the markers <!-- eval:begin --> and <!-- eval:end --> (appended when absent) with the
issue's targets, checked against results.json, followed by EVAL_DIR/summary.md. Everything else
in RESULTS.md is kept.
"""
import json
import os
import shutil
import sys

from results_section import splice



def fmt(v, pct=False):
    if v is None:
        return "-"
    return "%.1f%%" % (100 * v) if pct else "%.3f" % v


def targets(res):
    """Rows (what, target, measured, met) for the high-accuracy preset."""
    ours = next((p for p in res["presets"] if p.get("table_i_row") == "Ours"), None)
    if ours is None:
        ours = next((p for p in res["presets"] if p["name"] == "high_accuracy"), res["presets"][0])
    splits = [s for s in ours["splits"] if s["day"] is not None]
    if not splits:
        return []
    first = min(splits, key=lambda s: s["day"])
    last = max(splits, key=lambda s: s["day"])
    rows = []

    def add(what, target, value, ok, pct=False):
        rows.append((what, target, fmt(value, pct), "met" if ok else "missed"))

    r1 = lambda s: s["recall_at_n"][0]
    add("Recall@1, high accuracy, %s" % first["name"], ">= 0.98", r1(first), r1(first) >= 0.98)
    add("Recall@1, high accuracy, %s (oldest)" % last["name"], ">= 0.95", r1(last), r1(last) >= 0.95)
    loc = lambda s: s["localization"]["success_rate"]
    add("Localization success, %s" % first["name"], ">= 99%", loc(first), loc(first) >= 0.99, True)
    add("Localization success, %s (oldest)" % last["name"], ">= 95%", loc(last), loc(last) >= 0.95, True)
    sep = min(s["separation"]["kept_relevant"] for s in ours["splits"])
    add("Score separation, high accuracy (worst split; paper 91.21%)", ">= 95%", sep, sep >= 0.95, True)
    e2e = ours["timing"]["end_to_end"]["median_ms"]
    hz = 1000.0 / e2e if e2e else 0.0
    rows.append(("End-to-end localization rate, high accuracy, one core (paper: over 5 Hz)",
                 ">= 30 Hz", "%.1f Hz" % hz, "met" if hz >= 30 else "missed"))
    return rows


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    src, docs = sys.argv[1], sys.argv[2]
    with open(os.path.join(src, "results.json")) as f:
        res = json.load(f)
    with open(os.path.join(src, "summary.md")) as f:
        summary = f.read()
    os.makedirs(os.path.join(docs, "results"), exist_ok=True)
    pngs = sorted(p for p in os.listdir(src) if p.endswith(".png"))
    for p in pngs:
        shutil.copyfile(os.path.join(src, p), os.path.join(docs, "results", p))

    # The dataset by its directory name: no path of the machine that ran it.
    lines = ["## Evaluation: %s" % os.path.basename(os.path.normpath(res["dataset"]["path"])), ""]
    rows = targets(res)
    if rows:
        lines += ["| target | goal | measured | |", "| --- | --- | --- | --- |"]
        lines += ["| %s | %s | %s | %s |" % r for r in rows]
        lines.append("")
    lines += ["![%s](results/%s)" % (p[:-4], p) for p in pngs]
    lines.append("")
    # The summary's own title is replaced by the section heading above.
    body = summary.split("\n", 1)[1] if summary.startswith("# ") else summary
    lines += [body.replace("\n## ", "\n### ")]
    path = splice(docs, "eval", "\n".join(lines))
    print("wrote %s (%d plots in %s/results)" % (path, len(pngs), docs))


if __name__ == "__main__":
    main()
