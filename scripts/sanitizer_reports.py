#!/usr/bin/env python3
"""make test-sanitize: sorts the sanitizer log files of every process of the run.

A report of a defect fails the run: an AddressSanitizer error, a leak LeakSanitizer found, an
UndefinedBehaviorSanitizer runtime error, or any log this script cannot place.

A sanitizer's own crash is told apart and does not fail the run: LeakSanitizer stops every
thread with ptrace at exit and scans their stacks and thread-local storage; in a process that
is tearing down threads and unloading libraries meanwhile (a nodelet manager shut down by
roslaunch), its tracer thread can fault ("Tracer caught signal 11 ... LeakSanitizer has
encountered a fatal error"). That says nothing of our code, and the process's leak check did
not run: each such log is printed whole, named, and counted on a line of its own.

UndefinedBehaviorSanitizer, linked beside AddressSanitizer (GCC 12), ignores log_path and
prints its reports to the process's stderr: so the run's output (the test log, the ROS log
directory) is searched too, for the lines of a defect only (a test's ordinary output is not a
report).

Usage: sanitizer_reports.py REPORTS_DIR [OUTPUT_FILE_OR_DIR ...]. Exits 1 when any log reports a
defect."""
import os
import re
import sys

DEFECT = re.compile(
    r"ERROR: (AddressSanitizer|LeakSanitizer: detected memory leaks|UndefinedBehaviorSanitizer)"
    r"|runtime error:|SUMMARY: (AddressSanitizer|UndefinedBehaviorSanitizer|LeakSanitizer)")
TOOL_CRASH = re.compile(r"(LeakSanitizer|Sanitizer) has encountered a fatal error")


def classify(text):
    if DEFECT.search(text):
        return "defect"
    if TOOL_CRASH.search(text):
        return "tool"
    return "unknown"


def files_under(path):
    if os.path.isfile(path):
        return [path]
    return sorted(os.path.join(d, f) for d, _, fs in os.walk(path) for f in fs)


def texts_under(path):
    for name in files_under(path):
        with open(name, errors="replace") as f:
            yield name, f.read()


def main(root, outputs):
    defects, tools, unknown = [], [], []
    for path, text in texts_under(root):
        {"defect": defects, "tool": tools, "unknown": unknown}[classify(text)].append((path, text))
    for output in outputs:
        defects += [(path, text) for path, text in texts_under(output) if DEFECT.search(text)]
    for path, text in defects + unknown:
        first = next((l for l in text.splitlines() if DEFECT.search(l)), None)
        print(f"== {path}")
        print("   " + (first or "(a log this script cannot place; read it)").strip())
    for path, text in tools:
        print(f"== {path}: the sanitizer's own crash, not a report of a defect; this process's "
              "leak check did not run:")
        for line in text.strip().splitlines():
            print("   | " + line)
    if defects or unknown:
        print(f"sanitizer reports: {len(defects) + len(unknown)} (each one fails the run)")
    else:
        print("sanitizers: no report of a defect from any process (ASan, UBSan, LeakSanitizer)")
    if tools:
        print(f"sanitizer crashes of their own (not defects; leak check incomplete): {len(tools)}")
    return 1 if defects or unknown else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2:]))
