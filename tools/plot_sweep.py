#!/usr/bin/env python3
"""Plot `mireg sweep --csv` in the style of Zhang & Chen's Fig. 6.

One row per dataset, one panel per metric (recall, precision) against −μ (log), one line per ranking
for Lévy sampling; uniform and PROSAC are drawn per ranking on the right of each panel for comparison.

    mireg sweep LOG --csv > a.csv     # or: mireg sweep CLOUD_DIR --gt-log gt.log --csv > b.csv
    python3 tools/toolbox.py plot-sweep a.csv b.csv -o docs/sweep.png

The commands behind docs/sweep.png are in docs/REPRODUCTION.md.

Needs matplotlib (the `peers` group of tools/pyproject.toml).
"""
import argparse
import csv
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

HEADER = "dataset,ranking,sampler,mu,runs,pairs,recall,precision,hypotheses_median,time_s_median"
FIELDS = HEADER.split(",")
X_UNIFORM, X_PROSAC, X_SPLIT = 10**7.0, 10**7.8, 10**6.5  # right-hand slots, beyond −μ = 1e6
OTHERS = {"uniform": (X_UNIFORM, "s"), "prosac": (X_PROSAC, "^")}


def read_rows(paths):
    """All data rows of all files; repeated header lines and blank lines are skipped."""
    rows = []
    for path in paths:
        with (sys.stdin if path == "-" else open(path, newline="")) as f:
            for rec in csv.reader(f):
                if not rec or ",".join(rec).strip() == HEADER:
                    continue
                if len(rec) != len(FIELDS):
                    sys.exit(f"{path}: expected {len(FIELDS)} columns, got {rec}")
                rows.append(dict(zip(FIELDS, rec)))
    return rows


def num(s):
    try:
        return float(s)
    except ValueError:
        return math.nan


def distinct(values):
    return "/".join(dict.fromkeys(values))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv", nargs="+", help="CSV file(s) from `mireg sweep --csv` ('-' = stdin)")
    ap.add_argument("-o", "--output", default="docs/sweep.png")
    ap.add_argument("--dpi", type=int, default=120)
    ap.add_argument("--rankings", help="comma-separated rankings to plot (default: all)")
    ap.add_argument("--metric", default="recall,precision", help="comma-separated: recall, precision")
    args = ap.parse_args()

    metrics = [m.strip() for m in args.metric.split(",") if m.strip()]
    if not metrics or any(m not in ("recall", "precision") for m in metrics):
        ap.error("--metric takes recall and/or precision")
    rows = read_rows(args.csv)
    if args.rankings:
        keep = {r.strip() for r in args.rankings.split(",")}
        rows = [r for r in rows if r["ranking"] in keep]
    if not rows:
        sys.exit("no rows to plot")
    datasets = list(dict.fromkeys(r["dataset"] for r in rows))
    rankings = list(dict.fromkeys(r["ranking"] for r in rows))
    colors = {rk: plt.get_cmap("tab10")(k % 10) for k, rk in enumerate(rankings)}

    nrow, ncol = len(datasets), len(metrics)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.6 * ncol, 3.6 * nrow + 0.6), squeeze=False)
    for i, ds in enumerate(datasets):
        drows = [r for r in rows if r["dataset"] == ds]
        size = f"{distinct(r['pairs'] for r in drows)} pairs × {distinct(r['runs'] for r in drows)} runs"
        for j, metric in enumerate(metrics):
            ax = axes[i][j]
            for k, rk in enumerate(rankings):
                rr = [r for r in drows if r["ranking"] == rk]
                levy = sorted((-num(r["mu"]), num(r[metric])) for r in rr if r["sampler"] == "levy")
                levy = [p for p in levy if p[0] > 0]
                if levy:
                    ax.plot(*zip(*levy), color=colors[rk], marker="o", ms=4, lw=1.4, clip_on=False)
                # uniform / PROSAC: a short segment and a marker, nudged apart per ranking
                nudge = 10 ** (0.12 * (k - (len(rankings) - 1) / 2))
                for r in rr:
                    if r["sampler"] in OTHERS:
                        x, mk = OTHERS[r["sampler"]]
                        y = num(r[metric])
                        ax.plot([x / 10**0.25, x * 10**0.25], [y, y], color=colors[rk], lw=1, alpha=0.5)
                        ax.plot([x * nudge], [y], color=colors[rk], marker=mk, ms=6, ls="none", clip_on=False)
            ax.axvline(X_SPLIT, color="gray", lw=0.8, ls=":")
            ax.set_xscale("log")
            ax.set_xlim(0.5, 10**8.3)
            ax.set_ylim(0, 1.02)
            decades = [10.0**e for e in range(7)]
            ax.set_xticks(decades + [X_UNIFORM, X_PROSAC])
            ax.set_xticklabels(["1", "10", "10²", "10³", "10⁴", "10⁵", "10⁶", "uniform", "PROSAC"], fontsize=8)
            for t in ax.get_xticklabels()[-2:]:
                t.set_rotation(30)
            ax.set_xticks([m * d for d in decades[:-1] for m in range(2, 10)], minor=True)
            ax.grid(True, alpha=0.3)
            ax.set_title(f"{ds} — {metric} ({size})", fontsize=10)
            ax.set_ylabel(metric)
            if i == nrow - 1:
                ax.set_xlabel("−μ (Lévy location)")

    handles = [Line2D([], [], color=colors[rk], marker="o", ms=4, label=f"{rk} (Lévy)") for rk in rankings]
    handles += [
        Line2D([], [], color="gray", marker="s", ls="none", label="uniform (RANSAC)"),
        Line2D([], [], color="gray", marker="^", ls="none", label="PROSAC"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.45 / fig.get_figheight(), 1, 1))
    fig.savefig(args.output, dpi=args.dpi)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
