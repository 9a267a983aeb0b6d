#!/usr/bin/env python3
"""Sorts ThreadSanitizer reports (scripts/run_tsan.sh) into ours and third-party ones.

Only ground_texture_bow is built with -fsanitize=thread. roscpp, tf2_ros, log4cxx and boost's
compiled parts are Debian's, uninstrumented: TSan cannot see the synchronisation inside them
(a service response serialised on a spinner thread and handed to roscpp's poll thread, the
locks of roscpp's transports), so it reports races and lock-order cycles there that are not
real. A report is ours, and fails the run, when every one of its conflicting accesses (both
sides of a race; every edge of a lock-order cycle) has a frame in this package's own sources
(src/, include/ground_texture_bow/, test/). Frames without source names are symbolised here
from the module and offset that TSan printed. Reports in the third-party libraries are
counted and listed by their top frames.

Usage: tsan_reports.py REPORT_DIR WORKSPACE
Exit status: 1 when there is a report of ours, else 0.
"""
import collections
import glob
import os
import re
import subprocess
import sys

OURS = re.compile(r"ground_texture_bow/(src|include/ground_texture_bow|test)/")
FRAME = re.compile(r"^\s+#\d+\s+(?P<text>.*?)\s+\((?P<module>[^()+]+)\+(?P<offset>0x[0-9a-f]+)\)\s*$")
ACCESS = re.compile(r"^  (Read|Write|Atomic|Previous|Mutex M\d+ acquired here while holding)")


def reports(path):
    """The reports of one log file, each as a list of lines."""
    out, cur = [], None
    with open(path, errors="replace") as f:
        for line in f:
            line = line.rstrip("\n")
            if line.startswith("WARNING: ThreadSanitizer:"):
                cur = [line]
            elif cur is not None:
                cur.append(line)
                if line.startswith("SUMMARY: ThreadSanitizer:"):
                    out.append(cur)
                    cur = None
    return out


def sections(report):
    """(heading, frames) for each indented section of a report."""
    out = []
    for line in report[1:]:
        if line.startswith("  ") and not line.startswith("    "):
            out.append((line.strip(), []))
        elif out and FRAME.match(line):
            out[-1][1].append(line)
    return out


class Symbolizer:
    """Source locations of module+offset frames of this workspace's binaries (llvm-symbolizer)."""

    def __init__(self, workspace):
        self.paths = {}
        for p in glob.glob(os.path.join(workspace, "devel", "lib", "**", "*"), recursive=True):
            if os.path.isfile(p):
                self.paths.setdefault(os.path.basename(p), p)
        self.cache = {}

    def locations(self, module, offset):
        key = (module, offset)
        if key not in self.cache:
            path = self.paths.get(os.path.basename(module))
            text = ""
            if path:
                try:
                    text = subprocess.run(["llvm-symbolizer", "--inlining", "--obj=" + path, offset],
                                          capture_output=True, text=True, timeout=60).stdout
                except (OSError, subprocess.SubprocessError):
                    text = ""
            self.cache[key] = text
        return self.cache[key]


def frame_is_ours(line, sym):
    m = FRAME.match(line)
    if not m:
        return False
    if OURS.search(m.group("text")):
        return True
    return bool(OURS.search(sym.locations(m.group("module"), m.group("offset"))))


def top_frame(frames):
    for line in frames:
        m = FRAME.match(line)
        if m and "libsanitizer" not in m.group("text"):
            return "%s (%s)" % (m.group("text").split(" ")[0], os.path.basename(m.group("module")))
    return "?"


def main():
    report_dir, workspace = sys.argv[1], sys.argv[2]
    sym = Symbolizer(workspace)
    ours, theirs = [], collections.Counter()
    for path in sorted(glob.glob(os.path.join(report_dir, "*"))):
        for rep in reports(path):
            kind = rep[0].split("ThreadSanitizer:", 1)[1].split("(pid")[0].strip()
            accesses = [(h, fr) for h, fr in sections(rep) if ACCESS.match("  " + h)]
            if not accesses:
                accesses = [(h, fr) for h, fr in sections(rep) if fr]
            mine = bool(accesses) and all(any(frame_is_ours(l, sym) for l in fr) for _, fr in accesses)
            if mine:
                ours.append((os.path.basename(path), rep))
            else:
                where = " / ".join(sorted({top_frame(fr) for _, fr in accesses}))
                theirs["%s: %s" % (kind, where)] += 1
    total = sum(theirs.values())
    print("ThreadSanitizer: %d report(s) in uninstrumented third-party code (not counted):" % total)
    for what, n in theirs.most_common(8):
        print("  %4d  %s" % (n, what[:160]))
    if len(theirs) > 8:
        print("  ...   and %d more kinds" % (len(theirs) - 8))
    if ours:
        print("ThreadSanitizer: %d report(s) with ground_texture_bow on every side (each fails the run):"
              % len(ours))
        for name, rep in ours[:5]:
            print("== " + name)
            print("\n".join(rep[:60]))
        return 1
    print("ThreadSanitizer: no report with ground_texture_bow on every side")
    return 0


if __name__ == "__main__":
    sys.exit(main())
