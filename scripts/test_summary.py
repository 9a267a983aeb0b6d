#!/usr/bin/env python3
"""Summarises catkin's JUnit results: per-suite lines, failures in detail, and a final
'N passed, N failed' line. Exits 1 on any failure, when no test ran, or when any one result
file holds no test case (a gtest filter that matches nothing, a renamed suite in a rostest)."""
import os
import sys
import xml.etree.ElementTree as ET


def main(root):
    passed = failed = skipped = 0
    failures = []
    for dirpath, _, files in os.walk(root):
        for name in sorted(files):
            if not name.endswith(".xml"):
                continue
            path = os.path.join(dirpath, name)
            try:
                tree = ET.parse(path)
            except ET.ParseError as e:
                failed += 1
                failures.append(f"{path}: unreadable result file ({e})")
                continue
            cases = list(tree.iter("testcase"))
            if not cases:
                failed += 1
                failures.append(f"FAILED {path}: no test ran (a filter that selects nothing?)")
            for case in cases:
                label = f"{case.get('classname', '')}.{case.get('name', '')}"
                bad = case.find("failure") if case.find("failure") is not None else case.find("error")
                if bad is not None:
                    failed += 1
                    msg = (bad.get("message") or bad.text or "").strip().splitlines()
                    failures.append(f"FAILED {label}: {msg[0] if msg else ''}")
                elif case.find("skipped") is not None or case.get("status") == "notrun":
                    skipped += 1
                else:
                    passed += 1
    for f in failures:
        print(f)
    if passed + failed == 0:
        print("no test results found under", root)
        print("0 passed, 1 failed")
        return 1
    line = f"{passed} passed, {failed} failed"
    if skipped:
        line += f", {skipped} skipped"
    print(line)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "build/ws/build/test_results"))
