#!/usr/bin/env python3
"""Plot gtbow bench's scaling.json: query time, memory, insertion and load time against the
number of database images, both axes logarithmic. Usage: plot_scaling.py scaling.json out.png"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    with open(sys.argv[1]) as f:
        data = json.load(f)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    ax_q, ax_m, ax_t = axes
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red"]
    real = data["real_images"]
    for color, preset in zip(colors, data["presets"]):
        sizes = preset["sizes"]
        n = [s["images"] for s in sizes]
        for q in (0, 1):
            t = [s["query_ms"][q]["median"] for s in sizes]
            p95 = [s["query_ms"][q]["p95"] for s in sizes]
            style = "-o" if q == 0 else "--s"
            threads = sizes[0]["query_ms"][q]["threads"]
            ax_q.plot(n, t, style, color=color, label=f"{preset['name']}, {threads} thread{'s' if threads > 1 else ''}")
            if q == 0:
                ax_q.fill_between(n, t, p95, color=color, alpha=0.12)
        ax_m.plot(n, [s["rss_loaded_bytes"] / 1e9 for s in sizes], "-o", color=color,
                  label=f"{preset['name']}: resident (loaded map)")
        ax_m.plot(n, [s["index_bytes"] / 1e9 for s in sizes], ":", color=color,
                  label=f"{preset['name']}: online index")
        ax_t.plot(n, [s["insert_us"]["median"] / 1e3 for s in sizes], "-o", color=color,
                  label=f"{preset['name']}: insertion (median)")
        ax_t.plot(n, [s["load_warm_ms"] for s in sizes], "--^", color=color,
                  label=f"{preset['name']}: load (warm)")
        cold = [(s["images"], s["load_cold_ms"]) for s in sizes if s["load_cold_ms"] >= 0]
        if cold:
            ax_t.plot([c[0] for c in cold], [c[1] for c in cold], ":v", color=color,
                      label=f"{preset['name']}: load (cold)")
    targets = {"high_accuracy": (30, 8), "fast": (8, 4)}
    for color, preset in zip(colors, data["presets"]):
        if preset["name"] in targets:
            q, m = targets[preset["name"]]
            ax_q.plot([1e6], [q], "*", color=color, markersize=14, label=f"target {preset['name']} ({q} ms)")
            ax_m.plot([1e6], [m], "*", color=color, markersize=14, label=f"target {preset['name']} ({m} GB)")
    ax_t.plot([1e6], [5000], "k*", markersize=14, label="target load (5 s)")
    for ax, title, ylabel in ((ax_q, "query time (median; band: to p95)", "ms"),
                              (ax_m, "memory", "GB"),
                              (ax_t, "insertion and load", "ms")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.axvline(real, color="gray", lw=0.8, ls="--")
        ax.text(real, ax.get_ylim()[0], " synthetic beyond", color="gray", fontsize=8, va="bottom")
        ax.set_xlabel("database images")
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("gtbow bench: scaling to 1,000,000 images (" + str(real) + " real, rest synthetic)")
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)


if __name__ == "__main__":
    main()
