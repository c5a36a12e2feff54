"""The ``grid`` figure (Fig. 3c): the bars' scores as arena scale x distractor heatmaps, ours
beside the paper's."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

import bbs
from experiments.report.bars import bars_data
from experiments.report.binning import Stat
from experiments.report.context import Context
from experiments.report.style import fmt, markdown_table, missing_note, save_figure, step_label
from experiments.spec import Run


@dataclass
class GridData:
    """Heatmaps: rows arena scales, columns distractor counts."""

    scales: list[float]
    distractors: list[int]
    methods: list[str]
    at: list[int]
    tasks: dict[tuple[float, int], str]  # (scale, distractors) -> task
    ours: dict[tuple[str, int], np.ndarray]  # (method, at) -> [scale, distractors] mean
    ours_std: dict[tuple[str, int], np.ndarray]
    paper: dict[tuple[str, int], np.ndarray]
    paper_std: dict[tuple[str, int], np.ndarray]
    missing: list[Run]


def grid_data(context: Context, at: Iterable[int]) -> GridData:
    """The bars' values (:func:`bars_data`) laid out as arena scale x distractor count."""
    bars = bars_data(context, at)
    layout = {}
    for task in context.experiment.tasks:
        if task not in bbs.VARIANTS:
            raise ValueError(f"grid figure: {task!r} is not a BringBackShapes variant")
        kwargs = bbs.VARIANTS[task]
        layout[(float(kwargs["arena_scale"]), int(kwargs["num_distractors"]))] = task
    scales = sorted({s for s, _ in layout})
    counts = sorted({d for _, d in layout})
    tables = {name: {} for name in ("ours", "ours_std", "paper", "paper_std")}
    for method in bars.methods:
        for step in bars.at:
            for name in tables:
                tables[name][(method, step)] = np.full((len(scales), len(counts)), np.nan)
            for (scale, count), task in layout.items():
                entry = bars.values.get((task, method, step), {})
                cell = (scales.index(scale), counts.index(count))
                for source in ("ours", "paper"):
                    stat = entry.get(source, Stat())
                    tables[source][(method, step)][cell] = stat.mean
                    tables[f"{source}_std"][(method, step)][cell] = stat.std
    missing = bars.missing + [run for run, _ in bars.missing_at]
    return GridData(scales, counts, bars.methods, bars.at, layout, tables["ours"],
                    tables["ours_std"], tables["paper"], tables["paper_std"], missing)


def draw_grid(data: GridData, stem: Path) -> list[Path]:
    columns = [(step, source) for step in data.at for source in ("ours", "paper")]
    figure = Figure(figsize=(2.9 * len(columns) + 1.0, 2.6 * len(data.methods) + 0.8),
                    layout="constrained")
    axes = figure.subplots(len(data.methods), len(columns), squeeze=False)
    values = [v for table in (data.ours, data.paper) for v in table.values()]
    finite = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.array([])
    vmax = float(finite.max()) if finite.size else 1.0
    image = None
    for row, method in enumerate(data.methods):
        for column, (step, source) in enumerate(columns):
            ax = axes[row][column]
            mean = getattr(data, source)[(method, step)]
            std = getattr(data, f"{source}_std")[(method, step)]
            image = ax.imshow(np.ma.masked_invalid(mean), cmap="viridis", vmin=0,
                              vmax=max(vmax, 1e-9), origin="upper")
            for i in range(len(data.scales)):
                for j in range(len(data.distractors)):
                    text = (f"{mean[i, j]:.2f}\n±{std[i, j]:.2f}" if np.isfinite(mean[i, j])
                            else "missing")
                    light = np.isfinite(mean[i, j]) and mean[i, j] < 0.6 * vmax
                    ax.text(j, i, text, ha="center", va="center", fontsize=6,
                            color="white" if light else "black")
            ax.set_xticks(range(len(data.distractors)), data.distractors, fontsize=7)
            ax.set_yticks(range(len(data.scales)), [f"{s:g}" for s in data.scales], fontsize=7)
            ax.set_title(f"{method}, {source}, {step_label(step)}", fontsize=8)
            if row == len(data.methods) - 1:
                ax.set_xlabel("distractors", fontsize=8)
            if column == 0:
                ax.set_ylabel("arena scale", fontsize=8)
    if image is not None:
        figure.colorbar(image, ax=axes, shrink=0.6, label="eval return")
    note = missing_note(data.missing, width=int(figure.get_figwidth() * 11))
    figure.suptitle("score by arena scale x distractors (mean ± std over seeds)"
                    + (f"\n{note}" if note else ""), fontsize=9)
    return save_figure(figure, stem)


def grid_markdown(data: GridData) -> str:
    parts = []
    for method in data.methods:
        for step in data.at:
            rows = [["scale \\ distractors", *map(str, data.distractors)]]
            for i, scale in enumerate(data.scales):
                cells = []
                for j in range(len(data.distractors)):
                    ours, paper = data.ours[(method, step)][i, j], data.paper[(method, step)][i, j]
                    cells.append(f"{fmt(ours)} / {fmt(paper)}")
                rows.append([f"{scale:g}", *cells])
            parts.append(f"{method} at {step_label(step)} (ours / paper):\n\n"
                         + markdown_table(rows))
    return "\n\n".join(parts)
