#!/usr/bin/python3
"""How the write_*.py scripts check what they report (the targets are in targets.py).

    chk = Check("real floors", strict=args.strict)
    chk.need(cond, "10 surfaces")          # an expected input: absent -> exit 2
    row = chk.target(t, value, label)      # a target: its table row (what, wanted, measured, verdict)
    chk.claim(ok, "what must hold")        # a claim without a bound
    chk.finish()                           # prints the verdicts; exits 2, 1 or returns

Exit codes: 0 every claim holds (OPEN targets may be missed, printed); 1 a claim (or, with
--strict, an OPEN target) is missed; 2 an expected input is absent or unreadable.
"""
import argparse
import json
import sys

from targets import CLAIM, OPEN

MISSING, MISSED = 2, 1


class InputMissing(Exception):
    """An expected input is absent: the check cannot be made."""


def fmt(value, unit):
    if value is None:
        return "-"
    if unit == "%":
        return "%.1f%%" % (100 * value)
    if unit == "rate":
        return "%.2g" % value
    if unit == "n":
        return "%d" % value
    if unit == "x":
        return "x%.2f" % value
    if unit == "":
        return "%.3f" % value
    return "%.2f %s" % (value, unit)


def wanted(t):
    if t.unit == "rate":
        return "%s %.3g" % (t.op, t.bound)
    if t.unit == "x":
        return "%s %gx" % (t.op, t.bound)
    if t.unit == "%":
        return "%s %g%%" % (t.op, 100 * t.bound)
    if t.unit in ("", "n"):
        return "%s %g" % (t.op, t.bound)
    return "%s %g %s" % (t.op, t.bound, t.unit)


def holds(t, value):
    if value is None:
        return False
    # A hair of slack for values printed and read back (a rate of 0.95 stored as 0.9499999).
    eps = 1e-9 * max(1.0, abs(t.bound))
    return value >= t.bound - eps if t.op == ">=" else value <= t.bound + eps


class Check:
    def __init__(self, name, strict=False):
        self.name = name
        self.strict = strict
        self.missing = []   # expected inputs absent
        self.failed = []    # claims missed (and OPEN targets with --strict)
        self.open_missed = []
        self.open_met = []
        self.passed = 0

    def need(self, ok, what):
        """An expected input; returns ok."""
        if not ok:
            self.missing.append(what)
        return ok

    def require(self, ok, what):
        """An expected input without which nothing else can be checked."""
        if not ok:
            self.missing.append(what)
            raise InputMissing(what)

    def target(self, t, value, label, measured=None):
        """Checks target `t` on `value`; returns the table row (what, wanted, measured, verdict)."""
        what = "%s: %s" % (label, t.what) if label else t.what
        shown = measured if measured is not None else fmt(value, t.unit)
        if holds(t, value):
            self.passed += 1
            if t.status == OPEN:
                self.open_met.append("%s (%s): %s; %s explains it as missed" % (what, wanted(t), shown, t.where))
            return (what, wanted(t), shown, "met")
        gap = "" if value is None or t.unit in ("%", "rate", "n", "x", "") else " by %.2f %s" % (
            abs(value - t.bound), t.unit)
        if t.unit == "%" and value is not None:
            gap = " by %.1f points" % (100 * abs(value - t.bound))
        line = "%s: %s, wanted %s" % (what, shown, wanted(t))
        if t.status == CLAIM or self.strict:
            self.failed.append(line)
        else:
            self.open_missed.append("%s (open target: %s)" % (line, t.where))
        return (what, wanted(t), shown, "missed" + gap)

    def claim(self, ok, what):
        if ok:
            self.passed += 1
        else:
            self.failed.append(what)
        return ok

    def finish(self):
        out = sys.stdout
        for m in self.open_missed:
            print("%s: missed, known: %s" % (self.name, m), file=out)
        for m in self.open_met:
            print("%s: NOW MET: %s" % (self.name, m), file=out)
        if self.missing:
            for m in self.missing:
                print("%s: MISSING INPUT: %s" % (self.name, m), file=out)
        for m in self.failed:
            print("%s: MISSED: %s" % (self.name, m), file=out)
        if self.missing:
            print("%s: FAILED: %d expected input(s) absent" % (self.name, len(self.missing)))
            sys.exit(MISSING)
        if self.failed:
            print("%s: FAILED: %d claim(s) missed" % (self.name, len(self.failed)))
            sys.exit(MISSED)
        print("%s: all claims hold (%d checked, %d open targets missed)"
              % (self.name, self.passed, len(self.open_missed)))


def load_json(chk, path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError) as e:
        chk.require(False, "%s (%s)" % (path, e))


def run(chk, fn):
    """Runs fn(); an absent key or file ends the check as a missing input (exit 2)."""
    try:
        fn()
    except InputMissing:
        pass
    except (KeyError, IndexError, TypeError) as e:
        chk.missing.append("the input lacks %r (%s)" % (e.args[0] if e.args else e, type(e).__name__))
    chk.finish()


def parser(doc):
    p = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--check", action="store_true",
                   help="check only: do not write docs/RESULTS.md")
    p.add_argument("--strict", action="store_true",
                   help="also fail on the open targets (those RESULTS.md reports as missed)")
    return p


def table(rows):
    lines = ["| target | wanted | measured | |", "| --- | --- | --- | --- |"]
    return lines + ["| %s | %s | %s | %s |" % r for r in rows]


def bench_section_main(doc, name, stem, section, heading, intro, rows_of, demote, plot):
    """The whole of a write_*.py for one benchmark command's output directory: reads
    BENCH_DIR/STEM.json, checks its targets (rows_of(data, chk)), and unless --check splices
    into DOCS/RESULTS.md the section `section`: the heading, intro(data), the targets, the
    command's Markdown (STEM.md, passed through demote) and its plot (STEM.png, copied to
    DOCS/results/PNG under `plot` = (PNG, alt text))."""
    import os
    import shutil
    from results_section import splice

    p = parser(doc)
    p.add_argument("bench_dir")
    p.add_argument("docs", nargs="?")
    a = p.parse_args()
    if not a.check and not a.docs:
        p.error("DOCS_DIR is needed unless --check")
    chk = Check(name, a.strict)

    def go():
        data = load_json(chk, os.path.join(a.bench_dir, stem + ".json"))
        rows = rows_of(data, chk)
        if a.check or chk.missing:
            return
        with open(os.path.join(a.bench_dir, stem + ".md")) as f:
            md = f.read()
        os.makedirs(os.path.join(a.docs, "results"), exist_ok=True)
        lines = [heading, "", intro(data), ""]
        lines += table(rows)
        lines += ["", demote(md).rstrip(), ""]
        png = os.path.join(a.bench_dir, stem + ".png")
        if os.path.exists(png):
            shutil.copy(png, os.path.join(a.docs, "results", plot[0]))
            lines += ["![%s](results/%s)" % (plot[1], plot[0]), ""]
        print("wrote %s" % splice(a.docs, section, "\n".join(lines)))

    run(chk, go)
