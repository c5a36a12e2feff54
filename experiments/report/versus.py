"""The ``versus`` figure and table: our methods against every method of the reference file on
the same tasks (e.g. DreamerV3's released curves), one panel per task in env steps and one in
wall minutes, and a table at given env steps with our wall minutes per run."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib.ticker
import numpy as np
from matplotlib.figure import Figure

from experiments.report.binning import Stat, binned, seed_stats, value_near
from experiments.report.context import Context
from experiments.report.reference import paper_task
from experiments.report.runs import Curve
from experiments.report.style import (
    colour,
    markdown_table,
    save_figure,
    step_label,
    write_missing_note,
)
from experiments.spec import Run

BAR_COLOUR = "black"  # the reference's methods are drawn in black, dashed


@dataclass
class VersusData:
    tasks: list[str]
    methods: list[str]  # ours
    bar_methods: list[str]  # the reference's
    ours: dict[tuple[str, str], list[Curve]]  # (task, our method) with runs -> seeds with scores
    bar: dict[tuple[str, str], list[Curve]]  # (task, reference method) -> its seeds
    missing: list[Run]
    spacing: float  # our grid: the runs' evaluation interval
    bar_spacing: float  # the reference's grid
    at: list[float]
    budget_minutes: float | None


def versus_data(context: Context, at=(), budget_minutes: float | None = None) -> VersusData:
    """Our seeds per task x method that the experiment has runs of (a group may train some of
    its tasks only) and the reference's seeds of the same task (every method of the reference
    file), cut at the experiment's ``train.steps``."""
    experiment = context.experiment
    ours, bar, missing = {}, {}, []
    bar_methods: list[str] = []
    planned = {(run.task, run.method) for run in experiment.runs}
    for task in experiment.tasks:
        for method in experiment.methods:
            if (task, method) not in planned:
                continue
            curves, absent = context.ours(task, method)
            ours[(task, method)] = curves
            missing.extend(absent)
        if context.reference is None:
            continue
        for (ref_task, ref_method), curves in context.reference.curves.items():
            if ref_task == paper_task(task):
                bar[(task, ref_method)] = [cut(c, context.steps) for c in curves]
                if ref_method not in bar_methods:
                    bar_methods.append(ref_method)
    spacing = (float(experiment.runs[0].config().train.eval_every) if experiment.runs
               else context.spacing)
    bar_spacing = context.reference.spacing if context.reference is not None else spacing
    return VersusData(list(experiment.tasks), list(experiment.methods), bar_methods, ours, bar,
                      missing, spacing, bar_spacing, [float(x) for x in at], budget_minutes)


def cut(curve: Curve, steps: float) -> Curve:
    keep = curve.xs <= steps
    return Curve(curve.xs[keep], curve.ys[keep], curve.seed,
                 None if curve.wall is None else curve.wall[keep])


def wall_minutes(curve: Curve) -> float | None:
    """The run's wall minutes at its last evaluation (None if it did not record them)."""
    if curve.wall is None or not len(curve.wall):
        return None
    return float(curve.wall[-1]) / 60.0


def draw_versus(data: VersusData, stem: Path, title: str = "") -> list[Path]:
    columns = max(len(data.tasks), 1)
    figure = Figure(figsize=(3.2 * columns, 5.6), layout="constrained")
    axes = figure.subplots(2, columns, squeeze=False)
    handles: dict[str, object] = {}
    for index, task in enumerate(data.tasks):
        steps_ax, wall_ax = axes[0][index], axes[1][index]
        for method in data.bar_methods:
            seeds = data.bar.get((task, method), [])
            if not seeds:
                continue
            x, mean, std, _ = seed_stats(binned(c, data.bar_spacing) for c in seeds)
            label = f"{method} (released)"
            (handle,) = steps_ax.plot(x, mean, color=BAR_COLOUR, ls="--", lw=1.2, label=label)
            steps_ax.fill_between(x, mean - std, mean + std, color=BAR_COLOUR, alpha=0.08, lw=0)
            handles.setdefault(label, handle)
            final = mean[-1]
            wall_ax.axhline(final, color=BAR_COLOUR, ls=":", lw=1.0)
            handle = wall_ax.lines[-1]
            handles.setdefault(f"{method} at {step_label(x[-1])} env steps", handle)
        for method in data.methods:
            seeds = data.ours.get((task, method), [])
            if not seeds:
                continue
            c = colour(method, data.methods)
            x, mean, std, _ = seed_stats(binned(s, data.spacing) for s in seeds)
            (handle,) = steps_ax.plot(x, mean, color=c, lw=1.6, label=method)
            steps_ax.fill_between(x, mean - std, mean + std, color=c, alpha=0.2, lw=0)
            handles.setdefault(method, handle)
            for seed in seeds:
                if seed.wall is not None:
                    wall_ax.plot(seed.wall / 60.0, seed.ys, color=c, lw=1.0, alpha=0.8)
        if data.budget_minutes:
            wall_ax.axvline(data.budget_minutes, color="gray", lw=0.8)
        wall_ax.set_ylim(steps_ax.get_ylim())
        wall_ax.set_xlim(left=0, right=max(wall_ax.get_xlim()[1], data.budget_minutes or 0))
        write_missing_note(steps_ax, [r for r in data.missing if r.task == task], 40)
        steps_ax.set_title(task, fontsize=9)
        steps_ax.set_xlabel("env steps", fontsize=8)
        wall_ax.set_xlabel("wall minutes (each seed)", fontsize=8)
        steps_ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(
            lambda value, _: step_label(value)))
        for ax in (steps_ax, wall_ax):
            ax.set_ylabel("eval return", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
    if handles:
        figure.legend(list(handles.values()), list(handles), loc="outside lower center",
                      ncols=min(len(handles), 5), fontsize=8)
    figure.suptitle(title or "ours (mean ± std over seeds; wall panels: each seed) against the "
                    "released curves (mean ± std over their seeds)", fontsize=10)
    return save_figure(figure, stem)


def stat_at(seeds: list[Curve], at: float, spacing: float) -> Stat:
    return Stat.of(value_near(c, at, spacing) for c in seeds)


def versus_markdown(data: VersusData) -> str:
    """Per task x our method: ours and the reference's mean ± std (n) at each ``at`` step, and
    our wall minutes per run (mean over seeds, and the longest)."""
    header = ["task", "method"] + [f"{step_label(a)} env steps" for a in data.at] + \
        ["wall min / run (mean, max)"]
    rows = [header]
    for task in data.tasks:
        for method in data.bar_methods:
            seeds = data.bar.get((task, method), [])
            if seeds:
                rows.append([task, f"{method} (released)"] + [
                    stat_at(seeds, a, data.bar_spacing).text(1) for a in data.at] + ["—"])
        for method in data.methods:
            if (task, method) not in data.ours:
                continue
            seeds = data.ours[(task, method)]
            walls = [w for w in map(wall_minutes, seeds) if w is not None]
            wall = f"{np.mean(walls):.1f}, {max(walls):.1f}" if walls else "—"
            rows.append([task, method] + [stat_at(seeds, a, data.spacing).text(1)
                                          for a in data.at] + [wall])
    text = markdown_table(rows)
    reached = []
    for method in data.methods:
        tasks = [task for task in data.tasks if (task, method) in data.ours]
        count = sum(1 for task in tasks if at_or_above(data, task, method))
        reached.append(f"{method}: {count} of {len(tasks)} task{'s' * (len(tasks) != 1)}")
    if data.at and data.bar_methods:
        text += (f"\n\nAt {step_label(data.at[-1])} env steps, at or above the mean of "
                 f"{', '.join(data.bar_methods)}: " + "; ".join(reached) + ".")
    text += (f"\n\nA value is the evaluation nearest to the step, at most one evaluation "
             f"interval away (ours {step_label(data.spacing)}, the released curves' "
             f"{step_label(data.bar_spacing)}). Wall minutes: each run's wall time at its last "
             "evaluation (compilation, prefill and evaluations included; a process training S "
             "seeds charges each 1/S).")
    return text


def at_or_above(data: VersusData, task: str, method: str) -> bool:
    """Our mean at the last ``at`` step is at or above every reference method's mean there."""
    if not data.at:
        return False
    ours = stat_at(data.ours.get((task, method), []), data.at[-1], data.spacing)
    bars = [stat_at(data.bar.get((task, m), []), data.at[-1], data.bar_spacing)
            for m in data.bar_methods]
    bars = [b for b in bars if b.n]
    return bool(ours.n and bars) and all(ours.mean >= b.mean for b in bars)


