#!/usr/bin/env python3
"""Plot `mireg simulate --csv` in the style of Zhang & Chen's Fig. 5.

One panel per sample size: unique outlier-free hypotheses (log) against the hypothesis budget (log),
one line per strategy, ±1 std as a band.

    cargo run --release -- simulate --csv > docs/simulation.csv
    python3 tools/plot_simulation.py docs/simulation.csv -o docs/simulation.png

Needs matplotlib (the `peers` group of tools/pyproject.toml).
"""
import argparse
import csv
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def label(row):
    if row["strategy"] == "levy":
        return f"Lévy μ={float(row['mu']):g}"
    return {"uniform": "uniform (RANSAC)", "prosac": "PROSAC"}[row["strategy"]]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv")
    ap.add_argument("-o", "--output", default="simulation.png")
    args = ap.parse_args()

    series = defaultdict(list)  # (s, label) -> [(budget, mean, std)]
    sizes, labels = [], []
    with open(args.csv, newline="") as f:
        for row in csv.DictReader(f):
            s, lab = int(row["sample_size"]), label(row)
            series[(s, lab)].append(
                (int(row["hypotheses"]), float(row["unique_outlier_free_mean"]), float(row["unique_outlier_free_std"]))
            )
            if s not in sizes:
                sizes.append(s)
            if lab not in labels:
                labels.append(lab)

    fig, axes = plt.subplots(1, len(sizes), figsize=(5 * len(sizes), 4.4), sharey=True)
    axes = axes if len(sizes) > 1 else [axes]
    cmap = plt.get_cmap("viridis")
    for ax, s in zip(axes, sizes):
        for k, lab in enumerate(labels):
            pts = sorted(series[(s, lab)])
            x = [p[0] for p in pts]
            y = [max(p[1], 0.1) for p in pts]
            lo = [max(p[1] - p[2], 0.1) for p in pts]
            hi = [p[1] + p[2] for p in pts]
            style = {"uniform (RANSAC)": dict(color="black", ls="--"), "PROSAC": dict(color="tab:red", ls="-.")}
            st = style.get(lab, dict(color=cmap(k / max(len(labels) - 1, 1)), ls="-"))
            ax.plot(x, y, marker="o", ms=3, label=lab, **st)
            ax.fill_between(x, lo, hi, color=st["color"], alpha=0.12)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"sample size s = {s}")
        ax.set_xlabel("hypotheses drawn")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("unique outlier-free hypotheses")
    axes[-1].legend(fontsize=8, loc="upper left")
    fig.suptitle("3000 correspondences, 300 inliers at Lévy(μ=−10, c=1) ranks (floor 0.1 = none)")
    fig.tight_layout()
    fig.savefig(args.output, dpi=120)


if __name__ == "__main__":
    main()
