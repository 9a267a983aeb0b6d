#!/usr/bin/python3
"""Puts a `gtbow eval` run of the default benchmark (make benchmark) into docs/RESULTS.md and
checks its targets (scripts/targets.py, EVAL).

    write_results.py [--check] [--strict] EVAL_DIR [DOCS_DIR]

Copies EVAL_DIR's PNG plots to DOCS_DIR/results/, and replaces the part of DOCS_DIR/RESULTS.md
between the markers <!-- eval:begin --> and <!-- eval:end --> (appended when absent) with the
targets, checked against results.json, followed by EVAL_DIR/summary.md. Everything else in
RESULTS.md is kept. --check writes nothing. Exits 1 when a claimed target is missed, 2 when
the run lacks a query day or a Table I row of the default benchmark (the section is written
first when only a target is missed).
"""
import os
import shutil

import targets as T
from report_check import Check, load_json, parser, run, table
from results_section import splice


def target_rows(res, chk):
    """Rows (what, wanted, measured, verdict) for the high-accuracy and fast presets."""
    rows_by = {p.get("table_i_row"): p for p in res["presets"] if p.get("table_i_row")}
    for r in T.EVAL_EXPECT["rows"]:
        chk.need(r in rows_by, "the Table I row %r (gtbow eval --ablation)" % r)
    out = []
    for row, pre in (("Ours", ""), ("Ours Fast", "fast_")):
        p = rows_by.get(row)
        if p is None:
            continue
        days = {s["day"]: s for s in p["splits"] if s["day"] is not None}
        for d in T.EVAL_EXPECT["days"]:
            chk.need(d in days, "%s: a query split of day %d" % (p["name"], d))
        if not days:
            continue
        first, last = days[min(days)], days[max(days)]
        loc = lambda s: s["localization"]["success_rate"]
        if row == "Ours":
            r1 = lambda s: s["recall_at_n"][0]
            out.append(chk.target(T.EVAL["recall1_first"], r1(first), first["name"]))
            out.append(chk.target(T.EVAL["recall1_oldest"], r1(last), last["name"]))
            out.append(chk.target(T.EVAL["loc_first"], loc(first), first["name"]))
            out.append(chk.target(T.EVAL["loc_oldest"], loc(last), last["name"]))
            sep = min(s["separation"]["kept_relevant"] for s in p["splits"])
            out.append(chk.target(T.EVAL["separation"], sep, ""))
            key = "e2e_hz"
        else:
            out.append(chk.target(T.EVAL["fast_loc_first"], loc(first), first["name"]))
            out.append(chk.target(T.EVAL["fast_loc_oldest"], loc(last), last["name"]))
            key = "fast_e2e_hz"
        e2e = p["timing"]["end_to_end"]["median_ms"]
        out.append(chk.target(T.EVAL[key], 1000.0 / e2e if e2e else 0.0, "",
                              "%.1f Hz (%.2f ms)" % (1000.0 / e2e if e2e else 0.0, e2e)))
    return out


def main():
    p = parser(__doc__)
    p.add_argument("eval_dir")
    p.add_argument("docs", nargs="?")
    a = p.parse_args()
    if not a.check and not a.docs:
        p.error("DOCS_DIR is needed unless --check")
    chk = Check("benchmark (eval)", a.strict)

    def go():
        res = load_json(chk, os.path.join(a.eval_dir, "results.json"))
        rows = target_rows(res, chk)
        if a.check or chk.missing:
            return
        with open(os.path.join(a.eval_dir, "summary.md")) as f:
            summary = f.read()
        os.makedirs(os.path.join(a.docs, "results"), exist_ok=True)
        pngs = sorted(n for n in os.listdir(a.eval_dir) if n.endswith(".png"))
        for n in pngs:
            shutil.copyfile(os.path.join(a.eval_dir, n), os.path.join(a.docs, "results", n))
        # The dataset by its directory name: no path of the machine that ran it.
        lines = ["## Evaluation: %s" % os.path.basename(os.path.normpath(res["dataset"]["path"])), ""]
        lines += table(rows) + [""]
        lines += ["![%s](results/%s)" % (n[:-4], n) for n in pngs]
        lines.append("")
        # The summary's own title is replaced by the section heading above.
        body = summary.split("\n", 1)[1] if summary.startswith("# ") else summary
        lines += [body.replace("\n## ", "\n### ")]
        path = splice(a.docs, "eval", "\n".join(lines))
        print("wrote %s (%d plots in %s/results)" % (path, len(pngs), a.docs))

    run(chk, go)


if __name__ == "__main__":
    main()
