"""The report of `pih lasa --all`: per-method summary, Markdown tables and the comparison figures.

Every cell is a number or "—" for a run that failed; failures are listed with their reasons. Means and
standard deviations are over the shapes whose run succeeded (the count is printed beside them).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from rflow.lasa import BENCHMARK_MANIFOLDS, LASA_SHAPES, METHODS, ShapeResult
from rflow.train import TrainConfig

MANIFOLD_LABELS = {"spd": "SPD", "uq": "UQ"}
METHOD_LABELS = {"rflow": "RiemannianFlow", "naive": "naive", "rgmm": "R-GMM", "fdm": "FDM"}
MULTIMODAL_SHAPES = ("Multi_Models_1", "Multi_Models_2", "Multi_Models_3", "Multi_Models_4")
PAPER_GAIN_OVER_NAIVE = {"spd": 8.2, "uq": 17.7}


def _ok(results: Iterable[ShapeResult], manifold: str, method: str,
        shapes: Sequence[str] | None = None) -> list[ShapeResult]:
    return [r for r in results if r.error is None and r.manifold == manifold and r.method == method
            and (shapes is None or r.shape in shapes)]


def summary(results: Sequence[ShapeResult], shapes: Sequence[str] | None = None) -> dict[str, dict[str, Any]]:
    """Per manifold and method: runs, failures, and mean and std (over shapes) of DTW and manifold distance.

    Returns:
        {manifold: {method: {"runs", "failed", "dtw_mean", "dtw_std", "distance_mean", "distance_std"}}}
        for the (manifold, method) pairs present (restricted to ``shapes`` when given).
    """
    out: dict[str, dict[str, Any]] = {}
    for manifold in BENCHMARK_MANIFOLDS:
        for method in METHODS:
            runs = [r for r in results if r.manifold == manifold and r.method == method
                    and (shapes is None or r.shape in shapes)]
            if not runs:
                continue
            ok = [r for r in runs if r.error is None]
            dtw = np.array([r.dtw for r in ok])
            dist = np.array([r.manifold_distance for r in ok])
            out.setdefault(manifold, {})[method] = {
                "runs": len(runs), "failed": len(runs) - len(ok),
                "dtw_mean": float(dtw.mean()) if ok else None, "dtw_std": float(dtw.std()) if ok else None,
                "distance_mean": float(dist.mean()) if ok else None,
                "distance_std": float(dist.std()) if ok else None,
            }
    return out


def gains(results: Iterable[ShapeResult], baseline: str = "naive") -> dict[str, dict[str, float]]:
    """Mean DTW of rflow and ``baseline`` per manifold over the shapes where both succeeded, and the gain
    100 (baseline - rflow) / baseline in % (the paper's gain over naive: 8.2 % SPD, 17.7 % UQ)."""
    results = list(results)
    out: dict[str, dict[str, float]] = {}
    for manifold in BENCHMARK_MANIFOLDS:
        flow = {r.shape: r.dtw for r in _ok(results, manifold, "rflow")}
        base = {r.shape: r.dtw for r in _ok(results, manifold, baseline)}
        shapes = [s for s in LASA_SHAPES if s in flow and s in base]
        if not shapes:
            continue
        mean_flow = float(np.mean([flow[s] for s in shapes]))
        mean_base = float(np.mean([base[s] for s in shapes]))
        out[manifold] = {"shapes": float(len(shapes)), "rflow": mean_flow, baseline: mean_base,
                         "gain_percent": 100.0 * (mean_base - mean_flow) / mean_base}
    return out


def _fmt(value: float | None, digits: int) -> str:
    return "—" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _per_shape_table(results: Sequence[ShapeResult], attr: str, digits: int) -> list[str]:
    combos = [(a, m) for a in BENCHMARK_MANIFOLDS for m in METHODS
              if any(r.manifold == a and r.method == m for r in results)]
    table = {(r.shape, r.manifold, r.method): r for r in results}
    head = ["Shape"] + [f"{MANIFOLD_LABELS[a]} {METHOD_LABELS[m]}" for a, m in combos]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for shape in LASA_SHAPES:
        if not any(r.shape == shape for r in results):
            continue
        cells = [shape]
        for a, m in combos:
            r = table.get((shape, a, m))
            cells.append("—" if r is None or r.error is not None else _fmt(getattr(r, attr), digits))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _summary_table(stats: dict[str, dict[str, Any]]) -> list[str]:
    lines = ["| manifold | method | runs ok | DTW mean | DTW std | distance mean | distance std |",
             "|---|---|---|---|---|---|---|"]
    for manifold, methods in stats.items():
        for method, s in methods.items():
            ok = f"{s['runs'] - s['failed']}/{s['runs']}"
            lines.append(f"| {MANIFOLD_LABELS[manifold]} | {METHOD_LABELS[method]} | {ok} "
                         f"| {_fmt(s['dtw_mean'], 1)} | {_fmt(s['dtw_std'], 1)} | {_fmt(s['distance_mean'], 4)} "
                         f"| {_fmt(s['distance_std'], 4)} |")
    return lines


def markdown_table(results: Sequence[ShapeResult], config: TrainConfig) -> str:
    """The Markdown report: summary per method, the multimodal shapes, gains of rflow, per-shape DTW and
    manifold distance, mean times per method, and the failures with their reasons."""
    methods = [m for m in METHODS if any(r.method == m for r in results)]
    text = [
        "# Riemannian LASA benchmark",
        "",
        "DTW: sum of Euclidean distances along the optimal warping path between each demo and the trajectory "
        "generated from its first point, in the z-scored tangent space at the goal, mean of 4 demos. "
        "Distance: mean manifold distance along the sequence (Log-Euclidean for SPD, ||2 Log(q conj(q_hat))|| "
        "in rad for UQ). Mean and std are over the shapes whose run succeeded; — marks a failed run. "
        f"RiemannianFlow and naive: {config.epochs} epochs, {config.model.layers} layers, "
        f"{config.model.activation}, {config.optimizer}, lr {config.lr:g}, batch {config.batch_size}, "
        f"seed {config.seed}. R-GMM: components by BIC; FDM: 150 translations (both deterministic).",
        "",
        "## Summary per method",
        "",
        *_summary_table(summary(results)),
    ]
    multimodal = summary(results, MULTIMODAL_SHAPES)
    if multimodal:
        text += ["", "## Multimodal shapes (Multi_Models_1-4)", "", *_summary_table(multimodal)]
    text += ["", "## Gain of RiemannianFlow (mean DTW over the shapes where both succeeded)", "",
             "| manifold | against | shapes | RiemannianFlow | other | gain % | paper gain % |",
             "|---|---|---|---|---|---|---|"]
    for baseline in (m for m in methods if m != "rflow"):
        for manifold, g in gains(results, baseline).items():
            paper = PAPER_GAIN_OVER_NAIVE[manifold] if baseline == "naive" else "—"
            text.append(f"| {MANIFOLD_LABELS[manifold]} | {METHOD_LABELS[baseline]} | {int(g['shapes'])} | "
                        f"{g['rflow']:.1f} | {g[baseline]:.1f} | {g['gain_percent']:.1f} | {paper} |")
    text += ["", "## DTW per shape", "", *_per_shape_table(results, "dtw", 1),
             "", "## Manifold distance per shape", "", *_per_shape_table(results, "manifold_distance", 4),
             "", "## Mean wall time per run (s)", "", "| method | train | generate |", "|---|---|---|"]
    for method in methods:
        ok = [r for r in results if r.method == method and r.error is None]
        train = float(np.mean([r.train_time_s for r in ok])) if ok else math.nan
        gen = float(np.mean([r.generate_time_s for r in ok])) if ok else math.nan
        text.append(f"| {METHOD_LABELS[method]} | {_fmt(train, 1)} | {_fmt(gen, 2)} |")
    failures = [r for r in results if r.error is not None]
    if failures:
        text += ["", "## Failures", ""] + [f"- {r.shape} {r.manifold} {r.method}: {r.error}" for r in failures]
    return "\n".join(text) + "\n"


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_results(path: Path, shape: str, panels: Sequence[tuple[ShapeResult, np.ndarray, np.ndarray]],
                 save: Callable[[Path, Any], Path]) -> Path | None:
    """Grid of 3-D plots (manifold x method) of z-scored tangent demos (grey) vs generated (colour), goal (star).

    Args:
        path: the PNG to write.
        shape: the shape's name (title).
        panels: (result, demos_z (N, M, 3), generated_z (N, M, 3)) of the successful runs.
        save: writes the figure atomically: save(path, figure) -> path.

    Returns:
        The PNG path, or None when there is nothing to plot.
    """
    if not panels:
        return None
    plt = _pyplot()
    panels = sorted(panels, key=lambda p: (p[0].manifold, METHODS.index(p[0].method)))
    manifolds = sorted({p[0].manifold for p in panels})
    methods = [m for m in METHODS if any(p[0].method == m for p in panels)]
    fig = plt.figure(figsize=(4.2 * len(methods), 3.8 * len(manifolds)))
    try:
        for r, demos_z, generated_z in panels:
            index = manifolds.index(r.manifold) * len(methods) + methods.index(r.method) + 1
            ax = fig.add_subplot(len(manifolds), len(methods), index, projection="3d")
            for k, (demo, gen) in enumerate(zip(demos_z, generated_z)):
                ax.plot(*demo.T, color="0.6", lw=1.0, label="demos" if k == 0 else None)
                ax.plot(*gen.T, color=f"C{k}", lw=1.2, label="generated" if k == 0 else None)
                ax.scatter(*demo[0], color="k", s=8)
            ax.scatter(*demos_z[0, -1], color="k", marker="*", s=60, label="goal")
            ax.set_title(f"{MANIFOLD_LABELS[r.manifold]} {METHOD_LABELS[r.method]}: DTW {r.dtw:.1f}", fontsize=9)
            ax.tick_params(labelsize=6)
            if index == 1:
                ax.legend(fontsize=7, loc="upper left")
        fig.suptitle(f"{shape}: z-scored tangent space at the goal", fontsize=10)
        fig.tight_layout()
        return save(path, fig)
    finally:
        plt.close(fig)


def plot_comparison(path: Path, results: Sequence[ShapeResult], save: Callable[[Path, Any], Path]) -> Path | None:
    """The paper's comparison figure: per manifold (columns), DTW per shape and method (top row, a red x where
    a run failed) and the mean and standard deviation of DTW per method over the shapes (bottom row).

    Returns:
        The PNG path, or None when no result is there.
    """
    manifolds = [a for a in BENCHMARK_MANIFOLDS if any(r.manifold == a for r in results)]
    methods = [m for m in METHODS if any(r.method == m for r in results)]
    shapes = [s for s in LASA_SHAPES if any(r.shape == s for r in results)]
    if not manifolds:
        return None
    plt = _pyplot()
    table = {(r.shape, r.manifold, r.method): r for r in results}
    width = 0.8 / len(methods)
    fig, axes = plt.subplots(2, len(manifolds), figsize=(max(6.0, 0.45 * len(shapes) + 2) * len(manifolds), 7),
                             squeeze=False, gridspec_kw={"height_ratios": [2, 1]})
    try:
        for col, manifold in enumerate(manifolds):
            top, bottom = axes[0, col], axes[1, col]
            stats = summary(results).get(manifold, {})
            for j, method in enumerate(methods):
                x = np.arange(len(shapes)) + (j - (len(methods) - 1) / 2) * width
                values = [table.get((s, manifold, method)) for s in shapes]
                heights = [r.dtw if r is not None and r.error is None else 0.0 for r in values]
                top.bar(x, heights, width, color=f"C{j}", label=METHOD_LABELS[method])
                failed = [xi for xi, r in zip(x, values) if r is not None and r.error is not None]
                top.plot(failed, [0.0] * len(failed), "x", color="red", ms=6)
                s = stats.get(method)
                if s and s["dtw_mean"] is not None:
                    bottom.bar(j, s["dtw_mean"], 0.6, yerr=s["dtw_std"], capsize=4, color=f"C{j}")
            top.set_xticks(np.arange(len(shapes)))
            top.set_xticklabels(shapes, rotation=70, fontsize=7)
            top.set_ylabel("DTW")
            top.set_title(f"{MANIFOLD_LABELS[manifold]}: DTW per shape", fontsize=10)
            top.legend(fontsize=8)
            bottom.set_xticks(range(len(methods)))
            bottom.set_xticklabels([METHOD_LABELS[m] for m in methods], fontsize=8)
            bottom.set_ylabel("DTW mean ± std")
        fig.tight_layout()
        return save(path, fig)
    finally:
        plt.close(fig)
