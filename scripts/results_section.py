#!/usr/bin/python3
"""Replaces one generated section of docs/RESULTS.md, keeping everything else.

A section is the text between <!-- NAME:begin --> and <!-- NAME:end -->; it is appended when
absent. Used by the write_*.py scripts (eval, scaling, bench_map, real, authors, verification,
descriptors, keypoints, soak; their targets in targets.py, checked with report_check.py) and
scripts/fuzz.sh (fuzz). Command line: results_section.py DOCS_DIR NAME FILE (FILE's text
becomes the section body).
"""
import os
import sys


def splice(docs, name, body):
    """Writes `body` (text without the markers) as section `name` of DOCS/RESULTS.md."""
    begin, end = "<!-- %s:begin -->" % name, "<!-- %s:end -->" % name
    block = "%s\n\n%s\n\n%s" % (begin, body.strip("\n"), end)
    path = os.path.join(docs, "RESULTS.md")
    old = open(path).read() if os.path.exists(path) else "# Results\n"
    if begin in old and end in old:
        new = old[:old.index(begin)] + block + old[old.index(end) + len(end):]
    else:
        new = old.rstrip("\n") + "\n\n" + block + "\n"
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(new)
    os.replace(tmp, path)
    return path


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    with open(sys.argv[3]) as f:
        print("wrote %s" % splice(sys.argv[1], sys.argv[2], f.read()))
