"""Figures of the peg-in-hole skill (matplotlib, Agg backend, PNG written by envs.io.owned_output.save_figure).

- `plot_loss`: training loss per epoch of each model (train and validation).
- `plot_skill`: like the paper's peg-in-hole figure: (a) positions in 3-D, (b) orientation projected on
  the tangent space at the goal, Log_g(q) (3 components) against time; demonstrations thin grey,
  generated plans dashed black, executed (measured) trajectories thick red.
- `plot_stiffness`: eigenvalues of the translational stiffness against time, demonstrated (thin grey) beside
  commanded in executed episodes (thick red), one panel per eigenvalue (smallest to largest).
- `plot_force_traces`: the wrist force of chosen episodes against time, with the force limit.
- `plot_outcomes`: every episode's outcome by reason over its hole-pose error and over where it ended.
- `plot_success_map`: success rate over two sweep axes (`pih sweep`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import numpy.typing as npt  # noqa: E402

from envs.errors import EnvError  # noqa: E402
from envs.io.owned_output import save_figure  # noqa: E402

FloatArray = npt.NDArray[np.float64]

DEMO_STYLE = {"color": "0.6", "lw": 1.0}
PLAN_STYLE = {"color": "k", "lw": 1.2, "ls": "--"}
EXEC_STYLE = {"color": "tab:red", "lw": 2.2}


@dataclass(frozen=True)
class PoseCurve:
    """A pose trajectory for plotting: times (K,), positions (K, 3) m, orientation tangent (K, 3) rad."""

    times_s: FloatArray
    pos: FloatArray
    rot_tangent: FloatArray

    def __post_init__(self) -> None:
        t, p, r = (np.asarray(a, dtype=float) for a in (self.times_s, self.pos, self.rot_tangent))
        if t.ndim != 1 or p.shape != (t.size, 3) or r.shape != (t.size, 3):
            raise EnvError(f"a pose curve needs times (K,), pos (K, 3), rot_tangent (K, 3); got {t.shape}, "
                           f"{p.shape}, {r.shape}")


def _save(fig: Any, path: str | os.PathLike[str]) -> Path:
    out = Path(path)
    if str(out.parent) and not out.parent.is_dir():
        plt.close(fig)
        raise EnvError(f"cannot write figure {out}: folder {out.parent} does not exist")
    return save_figure(fig, out, dpi=120)


def _finish(fig: Any, path: str | os.PathLike[str], title: str | None, fontsize: float | None = None) -> Path:
    """The figure's title (when given) above its laid-out axes, written to ``path`` (`_save`)."""
    if title:
        fig.suptitle(title, fontsize=fontsize)
    fig.tight_layout()
    return _save(fig, path)


def plot_loss(histories: Mapping[str, Mapping[str, Sequence[float]]], path: str | os.PathLike[str]) -> Path:
    """Loss curves (negative log-likelihood per transition and dimension) of each model.

    Args:
        histories: model name -> {"train_loss": [...], "val_loss": [...]}.
        path: PNG to write.

    Returns:
        The written path.
    """
    fig, axes = plt.subplots(1, max(len(histories), 1), figsize=(4.5 * max(len(histories), 1), 3.4), squeeze=False)
    for ax, (name, hist) in zip(axes[0], histories.items()):
        train = list(hist.get("train_loss", []))
        val = list(hist.get("val_loss", []))
        ax.plot(np.arange(1, len(train) + 1), train, label="train")
        if val:
            ax.plot(np.arange(1, len(val) + 1), val, label="validation")
        ax.set_title(f"{name} model")
        ax.set_xlabel("epoch")
        ax.set_ylabel("NLL per transition and dim (nats)")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    return _save(fig, path)


def plot_skill(demos: Sequence[PoseCurve], plans: Sequence[PoseCurve], executed: Sequence[PoseCurve],
               goal_pos: npt.ArrayLike, path: str | os.PathLike[str], title: str = "",
               plan_label: str = "generated") -> Path:
    """The paper's peg-in-hole figure: (a) 3-D positions, (b) Log_g(q) components against time.

    Args:
        demos: demonstrations.
        plans: generated trajectories (from the executed episodes' start poses), or what a policy commanded
            (``plan_label`` "commanded").
        executed: measured peg_tip trajectories.
        goal_pos: (3,) goal position (marked).
        path: PNG to write.
        title: figure title.
        plan_label: the legend's name of ``plans``.

    Returns:
        The written path.
    """
    fig = plt.figure(figsize=(15, 4.8))
    grid = fig.add_gridspec(1, 4, width_ratios=[1.5, 1, 1, 1])
    ax3 = fig.add_subplot(grid[0], projection="3d")
    comp_axes = [fig.add_subplot(grid[k + 1]) for k in range(3)]
    groups = (("demonstrations", demos, DEMO_STYLE), (plan_label, plans, PLAN_STYLE), ("executed", executed, EXEC_STYLE))
    for label, curves, style in groups:
        for i, c in enumerate(curves):
            lab = label if i == 0 else None
            ax3.plot(c.pos[:, 0], c.pos[:, 1], c.pos[:, 2], label=lab, **style)
            for k, ax in enumerate(comp_axes):
                ax.plot(c.times_s, c.rot_tangent[:, k], label=lab, **style)
    g = np.asarray(goal_pos, dtype=float)
    ax3.scatter([g[0]], [g[1]], [g[2]], color="tab:blue", marker="*", s=80, label="goal")
    for c in executed:
        ax3.scatter([c.pos[0, 0]], [c.pos[0, 1]], [c.pos[0, 2]], color="tab:red", s=15)
    ax3.set_xlabel("x (m)", labelpad=6)
    ax3.set_ylabel("y (m)", labelpad=6)
    ax3.set_zlabel("z (m)", labelpad=6)
    ax3.tick_params(labelsize=7)
    ax3.set_title("(a) position")
    ax3.legend(fontsize=7, loc="upper left")
    for k, ax in enumerate(comp_axes):
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"Log_g(q)[{k}] (rad)")
        ax.grid(alpha=0.3)
    for k, ax in enumerate(comp_axes):
        ax.set_title(f"(b{k + 1}) orientation: Log_g(q)[{k}]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.subplots_adjust(wspace=0.5)
    return _save(fig, path)


@dataclass(frozen=True)
class StiffnessCurve:
    """A translational stiffness profile for plotting: times (K,) s, stiffness (K, 3, 3) N/m (SPD)."""

    times_s: FloatArray
    stiffness: FloatArray

    def __post_init__(self) -> None:
        t, k = np.asarray(self.times_s, dtype=float), np.asarray(self.stiffness, dtype=float)
        if t.ndim != 1 or k.shape != (t.size, 3, 3):
            raise EnvError(f"a stiffness curve needs times (K,) and stiffness (K, 3, 3); got {t.shape}, {k.shape}")


def plot_stiffness(demos: Sequence[StiffnessCurve], executed: Sequence[StiffnessCurve],
                   path: str | os.PathLike[str], title: str = "") -> Path:
    """Eigenvalues lambda_1 <= lambda_2 <= lambda_3 of K(t) against time, demonstrated beside executed.

    Args:
        demos: the demonstrations' stiffness profiles.
        executed: the stiffness commanded in executed episodes.
        path: PNG to write.
        title: figure title.

    Returns:
        The written path.
    """
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for label, curves, style in (("demonstrations", demos, DEMO_STYLE), ("executed", executed, EXEC_STYLE)):
        for i, c in enumerate(curves):
            lam = np.linalg.eigvalsh(np.asarray(c.stiffness, dtype=float))
            for k, ax in enumerate(axes):
                ax.plot(c.times_s, lam[:, k], label=label if i == 0 else None, **style)
    for k, ax in enumerate(axes):
        ax.set_yscale("log")
        ax.set_xlabel("time (s)")
        ax.set_title(f"({chr(ord('a') + k)}) eigenvalue {k + 1} of K")
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("stiffness (N/m)")
    axes[0].legend(fontsize=8)
    return _finish(fig, path, title)


def outcome_kind(record: Mapping[str, Any]) -> str:
    """"seated" or the failure's kind: its reason up to the first ':' or ' (' ("time_limit", "force_limit", ...)."""
    if record.get("success"):
        return "seated"
    return str(record.get("reason", "error")).split(":")[0].split(" (")[0]


def plot_outcomes(records: Sequence[Mapping[str, Any]], path: str | os.PathLike[str], title: str = "") -> Path:
    """Every episode's outcome by reason (seated, time limit, force limit, error, ...) over what perturbed it and
    where it ended. Left: the hole-pose error drawn for the episode (offset mm, tilt deg; the yaw as the marker's
    size). Right: the peg's state at the end (depth below the opening mm, tilt against the hole axis deg), which
    tells a jam on the chamfer (~1 mm deep) from one in the hole or a peg that never arrived.

    Args:
        records: per-episode dicts (EpisodeRecord.to_dict): "success", "reason", "perturbation",
            "insertion_depth_mm", "tilt_deg".
        path: PNG to write.
    """
    kinds = sorted({outcome_kind(r) for r in records}, key=lambda k: (k != "seated", k))
    colours = {kind: ("tab:green" if kind == "seated" else f"C{3 + i}") for i, kind in enumerate(kinds)}
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    for kind in kinds:
        chosen = [r for r in records if outcome_kind(r) == kind]
        per = [r.get("perturbation") or {} for r in chosen]
        label = f"{kind} ({len(chosen)})"
        left.scatter([p.get("hole_offset_mm", 0.0) for p in per], [p.get("hole_tilt_deg", 0.0) for p in per],
                     s=[10.0 + 30.0 * abs(p.get("hole_yaw_deg", 0.0)) for p in per], color=colours[kind],
                     alpha=0.7, label=label)
        ended = [(r["insertion_depth_mm"], r["tilt_deg"]) for r in chosen
                 if r.get("insertion_depth_mm") is not None and r.get("tilt_deg") is not None]
        if ended:
            x, y = zip(*ended)
            right.scatter(x, y, s=14, color=colours[kind], alpha=0.7, label=label)
    left.set_xlabel("hole-pose error: offset (mm)")
    left.set_ylabel("hole-pose error: tilt (deg); marker size: |yaw|")
    left.set_title("outcome over the perturbation", fontsize=10)
    right.set_xlabel("depth below the opening at the end (mm)")
    right.set_ylabel("peg tilt against the hole axis at the end (deg)")
    right.set_title("where each episode ended", fontsize=10)
    for ax in (left, right):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return _finish(fig, path, title, fontsize=10)



def plot_protocol(summary: dict[str, Any], path: str | os.PathLike[str], title: str) -> Path:
    """Left: each demo seed's rate with its Wilson interval, the pooled rate and the between-seed interval.
    Right: each seed's episodes by outcome (seated and the failure kinds), stacked."""

    reps = [r for r in summary["replicates"] if r["episodes"]]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2))
    x = np.arange(len(reps))
    labels = [str(r["demo_seed"]) for r in reps]
    if reps:
        rates = np.array([100 * r["rate"] for r in reps])
        low = np.array([100 * r["rate_ci95"][0] for r in reps])
        high = np.array([100 * r["rate_ci95"][1] for r in reps])
        ax.errorbar(x, rates, yerr=[np.maximum(rates - low, 0.0), np.maximum(high - rates, 0.0)], fmt="o", color="C0", capsize=4,
                    label="seed's rate, 95 % Wilson")
        p, b = summary["pooled"], summary["between_seeds"]
        ax.axhline(100 * p["rate"], color="C1", lw=1.5, label=f"pooled {100 * p['rate']:.1f} %")
        ax.axhspan(100 * b["mean_rate_ci95"][0], 100 * b["mean_rate_ci95"][1], color="C1", alpha=0.15,
                   label="between-seed 95 % (t)")
        ax.set_ylim(max(0.0, min(low.min(), 100 * b["mean_rate_ci95"][0]) - 5.0), 101.0)
    ax.set_xticks(x, labels)
    ax.set_xlabel("demo seed (its own demos, training and starts)")
    ax.set_ylabel("seated (%)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower left")
    kinds = sorted({k for r in reps for k in r["failures_by_kind"]})
    bottom = np.zeros(len(reps))
    seated = np.array([r["successes"] for r in reps], dtype=float)
    bx.bar(x, seated, color="C2", label="seated")
    bottom += seated
    for i, kind in enumerate(kinds):
        counts = np.array([r["failures_by_kind"].get(kind, 0) for r in reps], dtype=float)
        bx.bar(x, counts, bottom=bottom, color=f"C{3 + i}", label=kind)
        bottom += counts
    bx.set_xticks(x, labels)
    bx.set_xlabel("demo seed")
    bx.set_ylabel("episodes")
    bx.set_title("outcomes by reason", fontsize=10)
    bx.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    return _save(fig, path)


_LINE_STYLES: tuple[str, ...] = ("-", "--", "-.")
"""Line styles of the traces of one outcome, in turn."""


def plot_force_traces(traces: Sequence[tuple[str, bool, npt.ArrayLike, npt.ArrayLike]], force_limit_n: float,
                      path: str | os.PathLike[str], title: str = "") -> Path:
    """The wrist force |F| (N) of chosen episodes against time, failures in shades of red and successes in shades of
    green, each episode its own shade and line style (so that overlapping traces stay apart), with the force limit
    (on the force held for its 5 ms window, so single 1 ms peaks may pass it).

    Args:
        traces: (label, success, times (K,) s, wrist force |F| (K,) N) per episode.
        force_limit_n: the task's limit (not drawn when infinite).
        path: PNG to write.
    """
    fig, ax = plt.subplots(figsize=(8, 4))
    counts = {True: sum(1 for t in traces if t[1]), False: sum(1 for t in traces if not t[1])}
    seen = {True: 0, False: 0}
    for label, success, times, force in traces:
        ok = bool(success)
        i, n = seen[ok], counts[ok]
        seen[ok] += 1
        shade = 0.9 - 0.35 * i / max(1, n - 1)  # dark to lighter within one outcome
        color = plt.get_cmap("Greens" if ok else "Reds")(shade)
        ax.plot(np.asarray(times, dtype=float), np.asarray(force, dtype=float), lw=1.2, alpha=0.9,
                color=color, ls=_LINE_STYLES[i % len(_LINE_STYLES)], label=label)
    if np.isfinite(force_limit_n):
        ax.axhline(force_limit_n, color="k", ls="--", lw=1.0, label=f"limit {force_limit_n:g} N (held 5 ms)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("wrist force |F| (N)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


AXIS_LABELS: Mapping[str, tuple[str, float]] = {
    "clearance_m": ("clearance (mm)", 1e3),
    "hole_error_m": ("hole-pose error (mm)", 1e3),
    "chamfer_m": ("chamfer (mm)", 1e3),
    "hole_error_deg": ("hole-pose error (deg)", 1.0),
    "pos_range_m": ("start range (cm)", 1e2),
    "stiffness": ("stiffness (N/m)", 1.0),
}


def _axis_values(cells: Sequence[Mapping[str, Any]], axis: str) -> list[Any]:
    """The values of a sweep axis: numbers ascending, texts (stiffness settings) in the order of the cells."""
    values = list(dict.fromkeys(c["settings"][axis] for c in cells))
    return values if any(isinstance(v, str) for v in values) else sorted(values)


def _axis_tick(axis: str, value: Any) -> str:
    """A tick label of a sweep axis value, in the unit of AXIS_LABELS."""
    return value if isinstance(value, str) else f"{value * AXIS_LABELS[axis][1]:g}"


@dataclass(frozen=True)
class SuccessMap:
    """The grids a success map draws: ``rows`` None for one row; per panel (a combination of the other axes'
    values) the success rate in % (NaN where no cell) and each cell's label."""

    rows: str | None
    columns: str
    row_values: list[Any]
    col_values: list[Any]
    others: list[str]
    panels: list[tuple[Any, ...]]
    grids: list[np.ndarray]
    labels: list[dict[tuple[int, int], str]]


def success_map(cells: Sequence[Mapping[str, Any]], rows: str | None, columns: str) -> SuccessMap:
    """Arrange sweep cell summaries on a (rows x columns) grid per panel (see `plot_success_map`).

    Raises:
        EnvError: no cells, or an axis missing from the cells' settings.
    """
    axes_needed = [columns] if rows is None else [rows, columns]
    if not cells or any(axis not in c["settings"] for c in cells for axis in axes_needed):
        raise EnvError(f"every cell needs settings {', '.join(map(repr, axes_needed))}")
    others = sorted({k for c in cells for k in c["settings"]} - {rows, columns})
    panels = sorted({tuple(c["settings"][k] for k in others) for c in cells})
    if rows is None:
        row_values: list[Any] = [None]
    else:
        row_values = _axis_values(cells, rows)
        row_values = row_values if isinstance(row_values[0], str) else row_values[::-1]  # numbers grow upwards
    col_values = _axis_values(cells, columns)
    grids, labels = [], []
    for panel in panels:
        grid = np.full((len(row_values), len(col_values)), np.nan)
        texts: dict[tuple[int, int], str] = {}
        for c in cells:
            if tuple(c["settings"][k] for k in others) != panel:
                continue
            i = 0 if rows is None else row_values.index(c["settings"][rows])
            j = col_values.index(c["settings"][columns])
            grid[i, j] = 100.0 * c["success_rate"]
            low, high = c["success_rate_ci95"]
            force = c.get("median_peak_wrist_force_n")
            texts[(i, j)] = f"{grid[i, j]:.0f}%\n[{100 * low:.0f}, {100 * high:.0f}]" + (
                "" if force is None else f"\n{force:.1f} N")
        grids.append(grid)
        labels.append(texts)
    return SuccessMap(rows, columns, row_values, col_values, others, panels, grids, labels)


def plot_success_map(cells: Sequence[Mapping[str, Any]], rows: str | None, columns: str,
                     path: str | os.PathLike[str], title: str = "") -> Path:
    """Heat map of the success rate over two sweep axes (or one: ``rows`` None draws a single row), one panel
    per combination of any other axes.

    Each square shows the rate in % with its 95 % Wilson interval and the median peak wrist force of the
    successes.

    Args:
        cells: sweep cell summaries (``settings``, ``success_rate``, ``success_rate_ci95``,
            ``median_peak_wrist_force_n``).
        rows, columns: the axes on the map's rows and columns (keys of ``settings``); rows None: one row.
        path: PNG to write.
        title: figure title.

    Raises:
        EnvError: an axis missing from the cells' settings, or an unwritable path.
    """
    m = success_map(cells, rows, columns)
    fig, axes = plt.subplots(1, len(m.panels), figsize=(1.4 * len(m.col_values) * len(m.panels) + 2.5,
                                                        1.0 * len(m.row_values) + 1.8), squeeze=False)
    row_label, col_label = ("" if rows is None else AXIS_LABELS[rows][0]), AXIS_LABELS[columns][0]
    image = None
    for ax, panel, grid, texts in zip(axes[0], m.panels, m.grids, m.labels):
        for (i, j), text in texts.items():
            ax.text(j, i, text, ha="center", va="center", fontsize=7, color="white" if grid[i, j] < 50 else "black")
        image = ax.imshow(grid, vmin=0.0, vmax=100.0, cmap="viridis", aspect="auto")
        ax.set_xticks(range(len(m.col_values)), [_axis_tick(columns, v) for v in m.col_values])
        ax.set_yticks([] if rows is None else range(len(m.row_values)),
                      [] if rows is None else [_axis_tick(rows, v) for v in m.row_values])
        ax.set_xlabel(col_label)
        ax.set_ylabel(row_label)
        if m.others:
            ax.set_title(", ".join(f"{AXIS_LABELS[k][0]} {_axis_tick(k, v)}" for k, v in zip(m.others, panel)),
                         fontsize=9)
    if image is not None:
        fig.colorbar(image, ax=axes[0].tolist(), label="seated (%)", shrink=0.9)
    fig.suptitle(title or "success rate (95 % Wilson interval, median peak wrist force of successes)", fontsize=10)
    return _save(fig, path)
