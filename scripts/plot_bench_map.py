#!/usr/bin/python3
"""Plot gtbow bench-map's bench_map.json: for each preset, the latency of every insertion and
query call around the map save (time line, the save shaded) and the latency distributions of
calls that overlapped the save against those that did not, with the 10 ms stall target.
Usage: plot_bench_map.py bench_map.json out.png"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

KINDS = (("add", "Add", "tab:blue"), ("query", "Query", "tab:orange"), ("localize", "Localize", "tab:green"))
STALL_MS = 10.0


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    with open(sys.argv[1]) as f:
        data = json.load(f)
    variants = data["variants"]
    fig, axes = plt.subplots(len(variants), 2, figsize=(15, 4.5 * len(variants)), squeeze=False)
    for (ax_t, ax_c), v in zip(axes, variants):
        save = v["save"]
        title = "%s, descriptors %s, %d keyframes" % (
            v["name"], "kept" if v["keep_descriptors"] else "dropped", v["keyframes"])
        for key, label, color in KINDS:
            calls = save[key]["calls"]
            ax_t.scatter([c[0] / 1e3 for c in calls], [max(c[1], 1e-3) for c in calls], s=4,
                         color=color, label=label, alpha=0.6)
            for during, style in ((True, "-"), (False, ":")):
                lat = sorted(c[1] for c in calls
                             if (c[0] < save["ms"] and c[0] + c[1] > 0) == during)
                if not lat:
                    continue
                frac = [(i + 1) / len(lat) for i in range(len(lat))]
                ax_c.plot([max(x, 1e-3) for x in lat], frac, style, color=color,
                          label="%s, %s the save (%d)" % (label, "during" if during else "without", len(lat)))
        ax_t.axvspan(0, save["ms"] / 1e3, color="gray", alpha=0.2, label="save (%.2f s)" % (save["ms"] / 1e3))
        ax_t.axhline(STALL_MS, color="red", lw=0.8, ls="--", label="%g ms" % STALL_MS)
        ax_t.set_yscale("log")
        ax_t.set_xlabel("call start, s after the save began")
        ax_t.set_ylabel("latency, ms")
        ax_t.set_title(title + ": every call")
        ax_t.grid(True, which="both", alpha=0.3)
        ax_t.legend(fontsize=7, markerscale=3)
        ax_c.axvline(STALL_MS, color="red", lw=0.8, ls="--", label="%g ms" % STALL_MS)
        ax_c.set_xscale("log")
        ax_c.set_xlabel("latency, ms")
        ax_c.set_ylabel("fraction of calls")
        ax_c.set_title(title + ": latency distribution")
        ax_c.grid(True, which="both", alpha=0.3)
        ax_c.legend(fontsize=7)
    fig.suptitle("gtbow bench-map: insertion and queries while the map is saved (%d real keyframes, "
                 "the rest synthetic)" % data["real_keyframes_available"])
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)


if __name__ == "__main__":
    main()
