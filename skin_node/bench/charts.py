"""PNG charts of benchmark results (matplotlib, Agg backend, no display needed)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import NullFormatter, ScalarFormatter  # noqa: E402

#: Accuracy measures of the speed/accuracy chart: (summary key, label, transform to "error").
ACCURACY = (
    ("volume_error_max", "worst |volume ratio - 1|", abs),
    ("region_volume_error_max", "worst |joint-region volume ratio - 1|", abs),
    ("collapse_mm", "max collapse (mm, radial proxy)", lambda v: -v),
    ("bulge_mm", "max bulge (mm, radial proxy)", abs),
    ("pairs_max", "max intersecting triangle pairs", abs),
    ("folds90_max", "max sharp folds (edges turned > 90 deg)", abs),
    ("surface_roughness_max", "max roughness (umbrella, / rest)", lambda v: v - 1.0),
    ("crossings_max", "max skin crossings (vertices, the paper's test)", abs),
    ("ref_mean_mm", "mean distance to converged reference (mm)", abs),
)

DPI = 80


def _base(name: str) -> str:
    return name.split("[")[0]


def _colours(names) -> dict:
    bases = sorted({_base(n) for n in names})
    cmap = plt.get_cmap("tab10")
    return {b: cmap(i % 10) for i, b in enumerate(bases)}


def pareto_front(x, y) -> np.ndarray:
    """Indices of the points no other point beats on both x and y (lower is better), by x."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    order = ok[np.lexsort((y[ok], x[ok]))]
    front, best = [], np.inf
    for i in order:
        if y[i] < best:
            front.append(i)
            best = y[i]
    return np.array(front, dtype=int)


def speed_accuracy(summaries: list, path: Path, title: str = "") -> Path:
    """(a) One scatter per accuracy measure: ms per frame (p50) against the
    measure, a colour per method, each method's Pareto front as a line, and the
    front over all methods dashed."""
    n = len(ACCURACY)
    cols = 4
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows))
    axes = np.atleast_1d(axes).ravel()
    colours = _colours([s["method"] for s in summaries])
    for ax, (key, label, f) in zip(axes, ACCURACY):
        xs = np.array([s.get("ms_total_p50", np.nan) for s in summaries], float)
        ys = np.array([f(s.get(key, np.nan)) for s in summaries], float)
        for b, c in colours.items():
            idx = np.array([i for i, s in enumerate(summaries) if _base(s["method"]) == b])
            ax.scatter(xs[idx], ys[idx], color=c, s=22, label=b, zorder=3)
            fr = idx[pareto_front(xs[idx], ys[idx])]
            if len(fr) > 1:
                ax.plot(xs[fr], ys[fr], color=c, lw=1.2, zorder=2)
        fr = pareto_front(xs, ys)
        if len(fr) > 1:
            ax.plot(xs[fr], ys[fr], "k--", lw=0.8, zorder=1)
        ax.set_xlabel("ms per frame (p50)")
        ax.set_ylabel(label, fontsize=8)
        if not np.any(np.isfinite(xs) & np.isfinite(ys) & (xs > 0)):
            # a measure none of these scenes has (deviation is the arm's alone):
            # an empty log axis would fail
            ax.text(0.5, 0.5, "not measured here", ha="center", va="center",
                    transform=ax.transAxes, fontsize=8, color="0.4")
            continue
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.grid(alpha=0.3)
    for ax in axes[n:]:
        ax.axis("off")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower right", fontsize=9)
    fig.suptitle(title or "speed against accuracy (lower is better; lines: Pareto fronts)")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def pose_sweeps(results: dict, path: Path, title: str = "") -> Path:
    """(b) Volume ratio and deviation against elbow bend 0..180 and wrist twist
    0..360 degrees; ``results[motion][method] = rows`` (per-frame dicts)."""
    motions = [m for m in ("elbow_sweep", "twist_sweep") if m in results]
    fig, axes = plt.subplots(len(motions), 2, figsize=(11, 3.6 * len(motions)), squeeze=False)
    names = sorted({n for m in motions for n in results[m]})
    colours = _colours(names)
    xl = {"elbow_sweep": "elbow bend (degrees)", "twist_sweep": "wrist twist (degrees)"}
    for r, m in enumerate(motions):
        a0, a1 = axes[r]
        for name, rows in results[m].items():
            c = colours[_base(name)]
            x = [row["x"] for row in rows]
            a0.plot(x, [row["volume_ratio"] for row in rows], color=c, label=name)
            a1.plot(x, [row["dev_min_mm"] for row in rows], color=c, label=f"{name} collapse")
            a1.plot(x, [row["dev_max_mm"] for row in rows], color=c, ls="--",
                    label=f"{name} bulge")
        a0.axhline(1.0, color="k", lw=0.6)
        a1.axhline(0.0, color="k", lw=0.6)
        for a in (a0, a1):
            a.set_xlabel(xl[m])
            a.grid(alpha=0.3)
        a0.set_ylabel("whole-mesh volume ratio")
        a1.set_ylabel("deviation (mm): min solid, max dashed")
        a0.legend(fontsize=8)
    fig.suptitle(title or "arm pose sweeps")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def stability_chart(results: list, path: Path, title: str = "") -> Path:
    """(c) Methods (rows) x failure cases (columns), green stable / red failed,
    each cell labelled with what failed."""
    methods = list(dict.fromkeys(r["method"] for r in results))
    cases = list(dict.fromkeys(r["case"] for r in results))
    grid = np.full((len(methods), len(cases)), np.nan)
    fig, ax = plt.subplots(figsize=(1.9 * len(cases) + 1.5, 0.6 * len(methods) + 1.4))
    for r in results:
        i, j = methods.index(r["method"]), cases.index(r["case"])
        grid[i, j] = 1.0 if r["stable"] else 0.0
        text = "stable" if r["stable"] else "\n".join(r["failed"])
        ax.text(j, i, text, ha="center", va="center", fontsize=7)
    ax.imshow(grid, cmap="RdYlGn", vmin=-0.3, vmax=1.3, aspect="auto")
    frames = {r["case"]: r["frames"] for r in results}
    ax.set_xticks(range(len(cases)), [f"{c}\n({frames[c]} frames)" for c in cases], fontsize=8)
    ax.set_yticks(range(len(methods)), methods)
    ax.set_title(title or "stability map")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def memory_chart(mem: dict, path: Path) -> Path:
    """Resident set size against frames, with the after-warm-up level."""
    f, v = np.array(mem["samples"]).T
    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.plot(f, v, "o-", ms=3)
    ax.axhline(mem["after_warmup_mb"] * 1.1, color="r", ls="--", lw=0.8, label="+10% of warm-up")
    ax.set_xlabel("frames")
    ax.set_ylabel("RSS (MB)")
    ax.set_ylim(0, max(v.max(), mem["after_warmup_mb"] * 1.1) * 1.15)
    ax.set_title(f"{mem['method']} on {mem['scene']}: start {mem['start_mb']:.0f}, "
                 f"peak {mem['peak_mb']:.0f}, end {mem['end_mb']:.0f} MB", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path
