#!/usr/bin/python3
"""Plots of a `gtbow eval` run: reads results.json, writes PNGs next to it.

    plot_eval.py RESULTS_JSON OUT_DIR

recall_at_n.png       Recall@N per preset, one panel per query split
score_histograms.png  top-10 scores of true and false results with the 99% rejection threshold
localization.png      localization success per query day, per preset
position_errors.png   distribution of position errors of the estimates
scaling.png           insertion and query time against database size (the paper's Fig. 3)
precision_recall.png  what a SLAM backend reads: precision against recall of the top-1 result
                      accepted by BoW score (dashed) and of the published loop closure accepted
                      by inliers (solid), one panel per split; R@100P in the legend
"""
import json
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def save(fig, out, name):
    fig.tight_layout()
    fig.savefig(os.path.join(out, name + ".png"), dpi=120)
    plt.close(fig)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    with open(sys.argv[1]) as f:
        res = json.load(f)
    out = sys.argv[2]
    os.makedirs(out, exist_ok=True)
    presets = res["presets"]
    ns = res["protocol"]["recall_n"]
    splits = [s["name"] for s in presets[0]["splits"]]

    # Recall@N, one panel per split.
    cols = min(3, len(splits))
    rows = math.ceil(len(splits) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.5 * cols, 3.5 * rows), squeeze=False)
    for i, name in enumerate(splits):
        ax = axes[i // cols][i % cols]
        for p in presets:
            s = next(x for x in p["splits"] if x["name"] == name)
            ax.plot(ns, s["recall_at_n"], marker="o", label=p["name"])
        ax.set_xscale("log")
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("N")
        ax.set_ylabel("Recall@N")
        ax.set_title(name)
        ax.grid(True, alpha=0.3)
    for j in range(len(splits), rows * cols):
        axes[j // cols][j % cols].axis("off")
    axes[0][0].legend(fontsize=8)
    save(fig, out, "recall_at_n")

    # Score histograms (all splits pooled), one panel per preset.
    fig, axes = plt.subplots(1, len(presets), figsize=(4.5 * len(presets), 3.5), squeeze=False)
    for ax, p in zip(axes[0], presets):
        rel = [v for s in p["splits"] for v in s["top10_scores_relevant"]]
        irr = [v for s in p["splits"] for v in s["top10_scores_irrelevant"]]
        hi = max(rel + irr + [1e-9])
        bins = [hi * k / 40 for k in range(41)]
        ax.hist(irr, bins=bins, alpha=0.6, label="false results", color="tab:red")
        ax.hist(rel, bins=bins, alpha=0.6, label="true results", color="tab:green")
        thr = p["splits"][-1]["separation"]["threshold"]
        kept = [s["separation"]["kept_relevant"] for s in p["splits"]]
        ax.axvline(thr, color="k", linestyle="--",
                   label="99%% rejection (%s): kept %s" % (p["splits"][-1]["name"],
                                                          ", ".join("%.0f%%" % (100 * k) for k in kept)))
        ax.set_yscale("log")
        ax.set_xlabel("score")
        ax.set_title(p["name"])
        ax.legend(fontsize=7)
    save(fig, out, "score_histograms")

    # Localization success per query day.
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for p in presets:
        pts = [(s["day"], s["localization"]["success_rate"]) for s in p["splits"]
               if s["day"] is not None and s["localization"]["success_rate"] is not None]
        pts.sort()
        if pts:
            ax.plot([d for d, _ in pts], [r for _, r in pts], marker="o", label=p["name"])
    ax.set_xlabel("query age (days)")
    ax.set_ylabel("localization success (4.8 mm, 1.5 deg)")
    ax.set_ylim(0, 1.02)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    save(fig, out, "localization")

    # Position error distribution of the estimates (cumulative).
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for p in presets:
        errs = sorted(e for s in p["splits"] for e in s["localization"]["position_error_mm"])
        if errs:
            ax.plot(errs, [(k + 1) / len(errs) for k in range(len(errs))], label=p["name"])
    ax.axvline(4.8, color="k", linestyle="--", label="4.8 mm")
    ax.set_xscale("log")
    ax.set_xlabel("position error (mm)")
    ax.set_ylabel("fraction of estimates")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    save(fig, out, "position_errors")

    # Scaling: insertion and query time against database size.
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for p in presets:
        pts = p.get("scaling", [])
        if not pts:
            continue
        n = [x["images"] for x in pts]
        axes[0].plot(n, [x["insertion"]["mean_ms"] for x in pts], marker="o", label=p["name"])
        axes[1].plot(n, [x["query"]["median_ms"] for x in pts], marker="o", label=p["name"])
    for ax, what in zip(axes, ["insertion (mean, ms)", "query (median, ms)"]):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("database images")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
    axes[1].legend(fontsize=8)
    save(fig, out, "scaling")

    # Precision-recall of what a backend reads, one panel per split.
    if all("backend" in s for p in presets for s in p["splits"]):
        fig, axes = plt.subplots(rows, cols, figsize=(4.5 * cols, 3.6 * rows), squeeze=False)
        for i, name in enumerate(splits):
            ax = axes[i // cols][i % cols]
            for k, p in enumerate(presets):
                b = next(x for x in p["splits"] if x["name"] == name)["backend"]
                color = "C%d" % k
                for key, style, what in (("pr_verified", "-", "verified"), ("pr_bow_top1", "--", "BoW top-1")):
                    c = b[key]
                    r100 = b["recall_at_100_precision_" + ("verified" if key == "pr_verified" else "bow_top1")]
                    ax.plot(c["recall"], c["precision"], style, color=color, drawstyle="steps-post",
                            label="%s, %s (R@100P %.2f)" % (p["name"], what, r100))
            ax.set_xlim(0, 1.02)
            ax.set_ylim(0, 1.02)
            ax.set_xlabel("recall")
            ax.set_ylabel("precision")
            ax.set_title(name)
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=6)
        for j in range(len(splits), rows * cols):
            axes[j // cols][j % cols].axis("off")
        save(fig, out, "precision_recall")


if __name__ == "__main__":
    main()
