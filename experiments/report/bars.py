"""The ``bars`` figure (Fig. 3b): the score at each ``at`` step (the nearest evaluation within
one grid bin), ours beside the paper's."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.patches import Patch

from experiments.report.binning import Stat, value_near
from experiments.report.context import Context
from experiments.report.style import (
    colour,
    hide_unused,
    markdown_table,
    missing_note,
    panel_grid,
    save_figure,
    step_label,
)
from experiments.spec import Run


@dataclass
class BarsData:
    tasks: list[str]
    methods: list[str]
    at: list[int]
    values: dict[tuple[str, str, int], dict[str, Stat]]  # (task, method, at) -> ours/paper
    missing: list[Run]  # runs without scores
    missing_at: list[tuple[Run, int]]  # runs with scores but no evaluation near the step


def bars_data(context: Context, at: Iterable[int]) -> BarsData:
    """Mean +- std over seeds of the evaluation nearest each ``at`` step (within one grid bin),
    ours and the paper's, per task x method."""
    experiment, spacing = context.experiment, context.spacing
    at = [int(step) for step in at]
    values, missing, missing_at = {}, [], []
    for task in experiment.tasks:
        for method in experiment.methods:
            runs = context.runs_of(task, method)
            if not runs:
                continue
            missing.extend(r for r in runs if context.records.scores(r) is None)
            paper = context.paper(task, method)
            for step in at:
                ours = []
                for run in runs:
                    curve = context.records.scores(run)
                    if curve is not None:
                        value = value_near(curve, step, spacing)
                        ours.append(value)
                        if value is None:
                            missing_at.append((run, step))
                entry = {"ours": Stat.of(ours)}
                if paper:
                    entry["paper"] = Stat.of(value_near(c, step, spacing) for c in paper)
                values[(task, method, step)] = entry
    return BarsData(experiment.tasks, experiment.methods, at, values, missing, missing_at)


def draw_bars(data: BarsData, stem: Path) -> list[Path]:
    panels = [(task, step) for task in data.tasks for step in data.at]
    rows, columns = panel_grid(len(panels))
    figure = Figure(figsize=(3.2 + 0.9 * len(data.methods) * columns, 3.0 * rows + 0.6),
                    layout="constrained")
    axes = figure.subplots(rows, columns, squeeze=False)
    width = 0.38
    for index, (task, step) in enumerate(panels):
        ax = axes[index // columns][index % columns]
        for position, method in enumerate(data.methods):
            entry = data.values.get((task, method, step))
            if entry is None:
                continue
            c = colour(method, data.methods)
            for offset, source in ((-width / 2, "ours"), (width / 2, "paper")):
                stat = entry.get(source)
                if stat is None:
                    continue
                x = position + offset
                if stat.n:
                    ax.bar(x, stat.mean, width, yerr=stat.std, color=c, capsize=3,
                           alpha=1.0 if source == "ours" else 0.45,
                           hatch=None if source == "ours" else "//", edgecolor="black", lw=0.5)
                else:
                    ax.text(x, 0, "missing", rotation=90, ha="center", va="bottom", fontsize=7,
                            color="firebrick")
        ax.set_xticks(range(len(data.methods)), data.methods, fontsize=8)
        ax.set_title(f"{task} at {step_label(step)} env steps", fontsize=9)
        ax.set_ylabel("eval return", fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    hide_unused(axes, len(panels), rows, columns)
    figure.legend([Patch(facecolor="white", edgecolor="black"),
                   Patch(facecolor="white", edgecolor="black", hatch="//")],
                  ["ours (solid)", "paper (hatched)"], loc="outside lower center", ncols=2,
                  fontsize=8)
    note = missing_note(data.missing + [run for run, _ in data.missing_at],
                        width=int(figure.get_figwidth() * 11))
    figure.suptitle("score at fixed env steps (mean ± std over seeds)"
                    + (f"\n{note}" if note else ""), fontsize=9)
    return save_figure(figure, stem)


def bars_markdown(data: BarsData) -> str:
    rows = [["task", "method", "step", "ours", "paper"]]
    for (task, method, step), entry in data.values.items():
        rows.append([task, method, step_label(step), entry["ours"].text(),
                     entry["paper"].text() if "paper" in entry else "no reference"])
    return markdown_table(rows)
