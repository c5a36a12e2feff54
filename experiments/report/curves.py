"""The ``curves`` figure: one panel per task, our mean +- std over seeds on the grid, the
paper's curve of the same method dashed in the same colour."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib.ticker
import numpy as np
from matplotlib.figure import Figure

from experiments.report.binning import bin_of, binned, seed_stats
from experiments.report.context import Context
from experiments.report.style import (
    colour,
    hide_unused,
    panel_grid,
    save_figure,
    step_label,
    write_missing_note,
)
from experiments.spec import Run


@dataclass
class Line:
    """A drawn curve: mean +- std over seeds on the grid (``n``: seeds at each point)."""

    task: str
    method: str
    source: str  # "ours" or "paper"
    x: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    n: np.ndarray
    paper_name: tuple[str, str] | None = None  # the reference file's (task, method)

    @property
    def label(self) -> str:
        return self.method if self.source == "ours" else f"{self.method} (paper)"


@dataclass
class CurvesData:
    tasks: list[str]
    methods: list[str]
    lines: dict[str, dict[str, Line]]  # task -> label -> line
    reference_drawn: list[tuple[str, str, str, str]]  # (task, method, paper task, paper method)
    missing: list[Run]
    spacing: float


def curves_data(context: Context) -> CurvesData:
    """Per task, our mean +- std over seeds on the grid and, where the reference has the same
    task and method, the paper's curve (cut at the grid point of the experiment's
    ``train.steps``)."""
    experiment, spacing = context.experiment, context.spacing
    lines: dict[str, dict[str, Line]] = {}
    drawn, missing = [], []
    for task in experiment.tasks:
        lines[task] = {}
        for method in experiment.methods:
            if not context.runs_of(task, method):
                continue
            curves, absent = context.ours(task, method)
            missing.extend(absent)
            if curves:
                x, mean, std, n = seed_stats(binned(c, spacing) for c in curves)
                lines[task][method] = Line(task, method, "ours", x, mean, std, n)
            paper = context.paper(task, method)
            if paper:
                x, mean, std, n = seed_stats(binned(c, spacing) for c in paper)
                keep = x <= max(bin_of(context.steps, spacing), x[0])
                name = context.reference.paper_names[(task, method)]
                line = Line(task, method, "paper", x[keep], mean[keep], std[keep], n[keep], name)
                lines[task][line.label] = line
                drawn.append((task, method, *name))
    return CurvesData(experiment.tasks, experiment.methods, lines, drawn, missing, spacing)


def draw_curves(data: CurvesData, stem: Path, title: str = "") -> list[Path]:
    rows, columns = panel_grid(len(data.tasks))
    figure = Figure(figsize=(max(3.6 * columns, 7.0), 2.8 * rows + 0.8 + 0.3 * (columns < 2)),
                    layout="constrained")
    axes = figure.subplots(rows, columns, squeeze=False)
    handles: dict[str, object] = {}
    for index, task in enumerate(data.tasks):
        ax = axes[index // columns][index % columns]
        for line in data.lines[task].values():
            c = colour(line.method, data.methods)
            if line.source == "ours":
                (handle,) = ax.plot(line.x, line.mean, color=c, lw=1.6, label=line.label,
                                    marker="o" if len(line.x) <= 5 else None, ms=3)
                ax.fill_between(line.x, line.mean - line.std, line.mean + line.std, color=c,
                                alpha=0.2, lw=0)
            else:
                (handle,) = ax.plot(line.x, line.mean, color=c, lw=1.2, ls="--",
                                    label=line.label)
            handles.setdefault(line.label, handle)
        write_missing_note(ax, [r for r in data.missing if r.task == task])
        if not data.lines[task]:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", color="gray")
        ax.set_title(task, fontsize=9)
        ax.set_xlabel("env steps", fontsize=8)
        ax.set_ylabel("eval return", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(
            lambda value, _: step_label(value)))
        ax.grid(alpha=0.3)
    hide_unused(axes, len(data.tasks), rows, columns)
    if handles:
        figure.legend(list(handles.values()), list(handles), loc="outside lower center",
                      ncols=min(len(handles), 6 if columns > 1 else 3), fontsize=8)
    figure.suptitle(title or f"learning curves (mean ± std over seeds, bins of "
                    f"{step_label(data.spacing)} steps)", fontsize=10)
    return save_figure(figure, stem)


def curves_text(data: CurvesData) -> str:
    """The report's paragraph under the figure: the binning and which paper curves it drew."""
    drawn = sorted({f"{m} ({pm} in the file)" if pm != m else m
                    for _, m, _, pm in data.reference_drawn})
    text = (f"Mean ± std over seeds, binned on a grid of {step_label(data.spacing)} env steps "
            "(an evaluation counts at the nearest grid point at or after it; a seed's latest "
            "evaluation in a bin is its value). Dashed: the paper's curve of the same method.")
    return text + (f" Reference curves drawn: {', '.join(drawn)}." if drawn
                   else " No reference curves for these methods.")
