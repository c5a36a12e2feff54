"""The ``summary`` figure: the final score per task x method, and our distance from the
paper's mean in units of the paper's seed std."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from matplotlib.figure import Figure

from experiments.report.binning import Stat, binned, value_near
from experiments.report.context import Context
from experiments.report.style import (
    colour,
    fmt,
    markdown_table,
    missing_note,
    save_figure,
    step_label,
)
from experiments.spec import Run


def std_units(ours: float, paper_mean: float, paper_std: float) -> float:
    """How many of the paper's seed stds ours lies above (positive) or below its mean."""
    difference = ours - paper_mean
    if paper_std > 0:
        return difference / paper_std
    return 0.0 if difference == 0 else math.copysign(math.inf, difference)


@dataclass
class SummaryRow:
    task: str
    method: str
    step: float | None  # our last common step (None: no scores)
    ours: Stat
    paper: Stat | None  # None: no reference for this task and method

    @property
    def difference(self) -> float:
        """(ours - paper) / paper's seed std: NaN without both, +-inf if the std is 0."""
        if self.paper is None or not self.paper.n or not self.ours.n:
            return math.nan
        return std_units(self.ours.mean, self.paper.mean, self.paper.std)


@dataclass
class SummaryData:
    rows: list[SummaryRow]
    missing: list[Run]


def summary_data(context: Context) -> SummaryData:
    """Per task x method: our score at our last common step (the last grid point every one of
    our seeds with scores reached), and the paper's there (nearest evaluation within a bin)."""
    experiment, spacing = context.experiment, context.spacing
    rows, missing = [], []
    for task in experiment.tasks:
        for method in experiment.methods:
            if not context.runs_of(task, method):
                continue
            curves, absent = context.ours(task, method)
            missing.extend(absent)
            seeds = [binned(c, spacing) for c in curves]
            common = set.intersection(*(set(s) for s in seeds)) if seeds else set()
            step = max(common) if common else None
            ours = Stat.of(s[step] for s in seeds) if step is not None else Stat()
            paper_curves = context.paper(task, method)
            paper = None
            if paper_curves:
                paper = (Stat.of(value_near(c, step, spacing) for c in paper_curves)
                         if step is not None else Stat())
            rows.append(SummaryRow(task, method, step, ours, paper))
    return SummaryData(rows, missing)


def summary_markdown(data: SummaryData) -> str:
    rows = [["task", "method", "step", "ours", "paper", "(ours - paper) / paper std"]]
    for row in data.rows:
        rows.append([row.task, row.method, step_label(row.step) if row.step is not None else "—",
                     row.ours.text(), row.paper.text() if row.paper is not None
                     else "no reference", fmt(row.difference)])
    return markdown_table(rows)


def draw_summary(data: SummaryData, stem: Path, methods: list[str]) -> list[Path]:
    rows = data.rows
    figure = Figure(figsize=(7.0, 0.25 * len(rows) + 1.6), layout="constrained")
    ax = figure.subplots()
    labels = [f"{row.task} {row.method}" for row in rows]
    for position, row in enumerate(rows):
        value = row.difference
        if math.isfinite(value):
            ax.barh(position, value, color=colour(row.method, methods))
        else:
            why = ("missing" if not row.ours.n else "no reference" if row.paper is None
                   else "paper missing at this step" if not row.paper.n else "paper std 0")
            ax.text(0, position, f" {why}", va="center", fontsize=7, color="firebrick")
    ax.set_yticks(range(len(rows)), labels, fontsize=7)
    ax.invert_yaxis()
    ax.axvline(0, color="black", lw=0.8)
    for bound in (-1, 1):
        ax.axvline(bound, color="gray", lw=0.6, ls=":")
    ax.set_xlabel("(ours − paper) / paper's seed std, at our last common step", fontsize=8)
    note = missing_note(data.missing, width=int(figure.get_figwidth() * 11))
    figure.suptitle("final score vs the paper" + (f"\n{note}" if note else ""), fontsize=9)
    return save_figure(figure, stem)
