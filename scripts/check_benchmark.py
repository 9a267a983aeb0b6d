#!/usr/bin/python3
"""Checks the claims of the small benchmark (run by `make test`) on a `gtbow eval --ablation`
results.json, and prints what it compared.

    check_benchmark.py [--full] RESULTS_JSON

Claims (issue 4):
  - every ablation row beats the DBoW row (mAP@1000, mean over the query splits), except
    "DBoW + AKM": on our synthetic asphalt a flat vocabulary with hard assignment does not beat
    DBoW2's tree (measured at 1,230 and 32,085 images, docs/RESULTS.md); its row is printed,
    and soft assignment must lift it ("DBoW + AKM + SA" above "DBoW + AKM"). On the small
    floor of `make test` (192 database images, vocabularies from 60 images) "DBoW + AKM + SA"
    is exempt too: it beats DBoW clearly at 32,085 images but not at this size; --full (the
    32,000-image benchmark) checks it;
  - the high-accuracy version beats the fast version on the oldest query split;
  - the high-accuracy version localizes the day-0 queries (success >= 90% on this small floor).
Exits 1 naming the first claim that does not hold.
"""
import json
import sys


def main():
    args = sys.argv[1:]
    full = "--full" in args
    args = [a for a in args if a != "--full"]
    if len(args) != 1:
        sys.exit(__doc__)
    with open(args[0]) as f:
        res = json.load(f)
    rows = {p["table_i_row"]: p for p in res["presets"] if p.get("table_i_row")}
    need = ["DBoW", "DBoW + SB", "DBoW + AKM", "DBoW + AKM + SA (r=3)", "DBoW + OV", "Ours Fast", "Ours"]
    missing = [r for r in need if r not in rows]
    if missing:
        sys.exit("results lack the ablation rows %s (run gtbow eval --ablation)" % missing)

    def mean_map(p):
        return sum(s["map_at_1000"] for s in p["splits"]) / len(p["splits"])

    failures = []
    base = mean_map(rows["DBoW"])
    print("mAP@1000, mean over %d query splits:" % len(rows["DBoW"]["splits"]))
    exempt = {"DBoW", "DBoW + AKM"} if full else {"DBoW", "DBoW + AKM", "DBoW + AKM + SA (r=3)"}
    for r in need:
        m = mean_map(rows[r])
        ok = r in exempt or m > base
        note = "" if m > base or r == "DBoW" else "   (not above DBoW%s)" % (": known, see docstring" if r in exempt else "")
        print("  %-24s %.3f%s" % (r, m, note))
        if not ok:
            failures.append("%s (%.3f) does not beat DBoW (%.3f)" % (r, m, base))
    akm, akm_sa = mean_map(rows["DBoW + AKM"]), mean_map(rows["DBoW + AKM + SA (r=3)"])
    if not akm_sa > akm:
        failures.append("soft assignment does not lift DBoW + AKM (%.3f -> %.3f)" % (akm, akm_sa))

    def by_day(p):
        return sorted((s for s in p["splits"] if s["day"] is not None), key=lambda s: s["day"])

    ha, fast = by_day(rows["Ours"]), by_day(rows["Ours Fast"])
    if not ha:
        sys.exit("no query split with a day")
    old_ha, old_fast = ha[-1]["map_at_1000"], fast[-1]["map_at_1000"]
    print("oldest split %s: high accuracy %.3f, fast %.3f" % (ha[-1]["name"], old_ha, old_fast))
    if not old_ha > old_fast:
        failures.append("high accuracy (%.3f) does not beat fast (%.3f) on %s" % (old_ha, old_fast, ha[-1]["name"]))
    loc = ha[0]["localization"]["success_rate"]
    print("localization, high accuracy, %s: %.1f%%" % (ha[0]["name"], 100 * loc))
    if not loc >= 0.9:
        failures.append("high accuracy localizes only %.1f%% of %s" % (100 * loc, ha[0]["name"]))
    if failures:
        print("FAILED: " + "; ".join(failures))
        sys.exit(1)
    print("all claims hold")


if __name__ == "__main__":
    main()
