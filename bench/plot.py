#!/usr/bin/python3
"""Plots of the benchmarks' measured data (Debian's matplotlib, /usr/bin/python3).

  bench/plot.py incremental bench/results/pipeline.json OUT.png   re-run bars (pipeline_bench)
  bench/plot.py scaling bench/results/scaling.json OUT.png        time vs elements (scaling_bench)

Every number drawn comes from the JSON the bench wrote; nothing is typed in here.
"""
import json
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def fit(xs, ys):
    """Least squares of log y = a + b log x; returns (b, a) or None."""
    pts = [(math.log(x), math.log(y)) for x, y in zip(xs, ys) if x > 0 and y > 0]
    if len(pts) < 2:
        return None
    n = len(pts)
    mx = sum(p[0] for p in pts) / n
    my = sum(p[1] for p in pts) / n
    sxx = sum((p[0] - mx) ** 2 for p in pts)
    if sxx == 0:
        return None
    b = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx
    return b, my - b * mx


def rerun_rank(label):
    """The order the bench runs its re-runs in (JSON objects come back sorted by name)."""
    for i, key in enumerate(["no change", "split.layers", "split.ratio", "curve.order", "shell.thickness"]):
        if key in label:
            return i
    return 99


def incremental(data, out):
    wfs = list(data["workflows"].items())
    fig, axes = plt.subplots(1, len(wfs), figsize=(5.2 * len(wfs), 3.8), squeeze=False)
    for ax, (name, wd) in zip(axes[0], wfs):
        cold = wd["cold_s"]
        reruns = sorted(wd.get("reruns", {}).items(), key=lambda kv: rerun_rank(kv[0]))
        labels = [k.replace("`", "").replace("--set ", "") for k, _ in reruns]
        runner = [100 * v["runner_s"] / cold for _, v in reruns]
        rest = [100 * (v["wall_s"] - v["runner_s"]) / cold for _, v in reruns]
        x = range(len(reruns))
        ax.bar(x, runner, color="#4c72b0", label="stages + runner (report.json seconds)")
        ax.bar(x, rest, bottom=runner, color="#dd8452", label="start-up + writing out/ (msh, vtu, nektar)")
        for i, (_, v) in enumerate(reruns):
            ax.text(i, runner[i] + rest[i], f"{v['wall_s']:.2f} s\n{v['percent_of_cold']:.1f}%", ha="center",
                    va="bottom", fontsize=7)
        ax.axhline(5, color="#c44e52", ls="--", lw=1, label="target for split-only: 5% of cold")
        ax.set_xticks(list(x))
        ax.set_xticklabels(labels, rotation=20, ha="right", fontsize=7)
        ax.set_ylabel("wall time, % of the cold run")
        ax.set_ylim(0, max([r + t for r, t in zip(runner, rest)] + [5]) * 1.6)
        ax.set_title(f"{name.split('/')[-1]}: re-runs vs cold run ({cold:.1f} s)", fontsize=9)
        ax.legend(fontsize=6.5, loc="upper left")
    fig.tight_layout()
    fig.savefig(out, dpi=90)


def scaling(data, out):
    sizes = [s for s in data["sizes"] if s.get("complete")]
    fig, ax = plt.subplots(figsize=(7, 4.6))
    xs = [s["elements"] for s in sizes]
    stages = data["stage_order"]
    cmap = plt.get_cmap("tab10")
    for i, st in enumerate(stages):
        ys = [s["stages"].get(st, {}).get("seconds", 0) for s in sizes]
        f = fit(xs, ys)
        lab = st + (f" ({f[0]:.2f})" if f else "")
        ax.loglog(xs, ys, "o-", ms=3, lw=1, color=cmap(i % 10), label=lab)
    ys = [s["wall_s"] for s in sizes]
    f = fit(xs, ys)
    ax.loglog(xs, ys, "s-", ms=5, lw=2.5, color="black", label="total wall" + (f" ({f[0]:.2f})" if f else ""))
    if f and xs:
        x0, x1 = xs[0], xs[-1]
        ax.loglog([x0, x1], [ys[0], ys[0] * (x1 / x0) ** 1.15], ":", color="grey", lw=1,
                  label="slope 1.15 from the smallest (target)")
    ax.set_xlabel("final elements (after split)")
    ax.set_ylabel("seconds")
    ax.set_title("NACA wing tip, P=4: time vs size (fitted exponent in brackets)", fontsize=9)
    ax.legend(fontsize=7, ncol=2, loc="upper left")
    ax.grid(True, which="both", lw=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=90)


def main():
    kind, src, out = sys.argv[1:4]
    with open(src) as f:
        data = json.load(f)
    {"incremental": incremental, "scaling": scaling}[kind](data, out)


if __name__ == "__main__":
    main()
