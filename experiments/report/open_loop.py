"""The ``open_loop`` figure and table: the world model's open-loop prediction error per imagined
step (the paper's imagined-rollout test as a number), one line per method, two panels per task
(observations, rewards), and a table at imagined steps 5, 15 and 35.

Each run's ``open_loop.jsonl`` (``vsgjax/loop/rundir.py``: one line per evaluation,
``{"step", "obs_mse": [35], "reward_mse": [35]}``, entry ``k - 1`` the error at imagined step
``k`` after 15 observed steps) gives one evaluation per seed: its last, or with ``at`` the one
nearest to that env step and at most one grid bin away (the bars' rule). Per imagined step the
mean and std are over the seeds that have a number there (a seed evaluated on short episodes
has fewer steps). A run without the file (a run not started) or without an evaluation near
``at`` is listed as missing; an agent without a world model (DrQ-v2) has neither a line nor a
row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.report.context import Context
from experiments.report.runs import is_number, read_jsonl, run_name, warn
from experiments.report.style import (
    colour,
    markdown_table,
    panel_grid,
    save_figure,
    step_label,
    write_missing_note,
)
from experiments.spec import Run
from vsgjax.loop.rundir import OPEN_LOOP_ERRORS, OPEN_LOOP_FILE, OPEN_LOOP_STEPS
from vsgjax.registry.agents import dreamer_models

PANELS = {"obs_mse": "observations", "reward_mse": "rewards"}  # panel titles per quantity


@dataclass
class ErrorLine:
    """One method's error per imagined step: mean +- std over seeds (``n``: seeds per step)."""

    task: str
    method: str
    quantity: str  # "obs_mse" or "reward_mse"
    x: np.ndarray  # imagined steps 1..H
    mean: np.ndarray
    std: np.ndarray
    n: np.ndarray
    steps: list[float]  # the env step of the evaluation each seed contributed

    def at(self, step: int) -> tuple[float, float, int]:
        """(mean, std, seeds) at imagined step ``step``; NaN and 0 where no seed reaches it."""
        index = np.flatnonzero(self.x == step)
        if not len(index) or not self.n[index[0]]:
            return math.nan, math.nan, 0
        i = index[0]
        return float(self.mean[i]), float(self.std[i]), int(self.n[i])


@dataclass
class OpenLoopData:
    tasks: list[str]
    methods: list[str]
    lines: dict[str, dict[str, dict[str, ErrorLine]]]  # task -> quantity -> method -> line
    at: float | None  # None: each seed's last evaluation
    spacing: float
    missing: list[Run]
    why: dict[Run, str] = field(default_factory=dict)  # missing run -> what was not found


def read_open_loop(path: Path, problems: list[str] | None = None) -> list[dict]:
    """The valid lines of an ``open_loop.jsonl`` (a number ``step`` and both error lists;
    null entries become NaN), in step order; others are skipped with a warning."""
    records = []
    for number, record in enumerate(read_jsonl(path, problems), 1):
        lists = [record.get(name) for name in OPEN_LOOP_ERRORS]
        if not is_number(record.get("step")) or not all(isinstance(v, list) for v in lists):
            warn(f"{path}: line {number} has no step and error lists; skipped", problems)
            continue
        records.append({"step": float(record["step"]), **{
            name: np.array([float(v) if is_number(v) else math.nan for v in values])
            for name, values in zip(OPEN_LOOP_ERRORS, lists, strict=True)}})
    return sorted(records, key=lambda r: r["step"])


def pick(records: list[dict], at: float | None, spacing: float) -> dict | None:
    """The last evaluation, or the one nearest to ``at`` within ``spacing`` (ties: the
    earlier); None when there is none."""
    if not records:
        return None
    if at is None:
        return records[-1]
    distance = [abs(r["step"] - at) for r in records]
    index = int(np.argmin(distance))
    return records[index] if distance[index] <= spacing else None


def per_step_stats(seeds: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    """(imagined steps 1..H, mean, std, seeds) over the seeds with a finite value at each step
    (H: the longest seed's)."""
    length = max(len(s) for s in seeds)
    columns = [[float(s[i]) for s in seeds if i < len(s) and math.isfinite(s[i])]
               for i in range(length)]
    nan = math.nan
    return (np.arange(1, length + 1), np.array([np.mean(c) if c else nan for c in columns]),
            np.array([np.std(c) if c else nan for c in columns]),
            np.array([len(c) for c in columns]))


def open_loop_data(context: Context, at: float | None = None) -> OpenLoopData:
    """Per task x method with runs: the error per imagined step of each seed's last evaluation
    (or the one nearest to ``at``), mean +- std over seeds."""
    experiment, spacing = context.experiment, context.spacing
    at = None if at is None else float(at)
    lines: dict[str, dict[str, dict[str, ErrorLine]]] = {}
    missing, why = [], {}
    world_models = dreamer_models()
    for task in experiment.tasks:
        lines[task] = {name: {} for name in OPEN_LOOP_ERRORS}
        for method in experiment.methods:
            chosen = []
            for run in context.runs_of(task, method):
                if run.model not in world_models:
                    continue  # no world model, nothing imagined
                differs = context.records.differs(run)
                path = run.logdir(context.records.root) / OPEN_LOOP_FILE
                records = read_open_loop(path, context.records.problems) \
                    if path.exists() and not differs else []
                record = pick(records, at, spacing)
                if record is None:
                    missing.append(run)
                    why[run] = (f"no evaluation within {step_label(spacing)} env steps of "
                                f"{step_label(at)} in `{path}`" if records else
                                f"`{path}`" + (f" (config differs: {differs})" if differs
                                               else ""))
                else:
                    chosen.append(record)
            if not chosen:
                continue
            for name in OPEN_LOOP_ERRORS:
                x, mean, std, n = per_step_stats([r[name] for r in chosen])
                lines[task][name][method] = ErrorLine(task, method, name, x, mean, std, n,
                                                      [r["step"] for r in chosen])
    return OpenLoopData(list(experiment.tasks), list(experiment.methods), lines, at, spacing,
                        missing, why)


def when(data: OpenLoopData) -> str:
    return ("at each seed's last evaluation" if data.at is None
            else f"at the evaluation nearest to env step {step_label(data.at)}")


def draw_open_loop(data: OpenLoopData, stem: Path, title: str = "") -> list[Path]:
    """Two panels per task (observations, rewards), up to two tasks a row."""
    rows, columns = panel_grid(len(data.tasks), max_columns=2)
    figure = Figure(figsize=(6.6 * columns, 2.7 * rows + 0.9), layout="constrained")
    axes = figure.subplots(rows, 2 * columns, squeeze=False)
    handles: dict[str, object] = {}
    for index, task in enumerate(data.tasks):
        row, column = divmod(index, columns)
        for offset, name in enumerate(OPEN_LOOP_ERRORS):
            ax = axes[row][2 * column + offset]
            for method, line in data.lines[task][name].items():
                c = colour(method, data.methods)
                (handle,) = ax.plot(line.x, line.mean, color=c, lw=1.5, label=method)
                ax.fill_between(line.x, line.mean - line.std, line.mean + line.std, color=c,
                                alpha=0.2, lw=0)
                handles.setdefault(method, handle)
            if not data.lines[task][name]:
                ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", color="gray")
            if offset == 0:
                write_missing_note(ax, [r for r in data.missing if r.task == task])
            ax.set_title(f"{task}: {PANELS[name]}", fontsize=9)
            ax.set_xlabel("imagined step", fontsize=8)
            ax.set_ylabel("MSE", fontsize=8)
            ax.set_ylim(bottom=0)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
    for index in range(len(data.tasks), rows * columns):
        row, column = divmod(index, columns)
        for offset in (0, 1):
            axes[row][2 * column + offset].set_visible(False)
    if handles:
        figure.legend(list(handles.values()), list(handles), loc="outside lower center",
                      ncols=min(len(handles), 6), fontsize=8)
    figure.suptitle(title or (f"open-loop prediction error per imagined step after the "
                              f"observed context, {when(data)} (mean ± std over seeds)"),
                    fontsize=10)
    return save_figure(figure, stem)


def cell(line: ErrorLine | None, step: int) -> str:
    if line is None:
        return "missing"
    mean, std, n = line.at(step)
    return f"{mean:.3g} ± {std:.2g} (n={n})" if n else "—"


def open_loop_markdown(data: OpenLoopData) -> str:
    """Per task x method: the env step of the evaluations used and the errors at imagined
    steps 5, 15 and 35; then the missing runs and the files looked for."""
    header = ["task", "method", "env step"] + [
        f"{PANELS[name][:-1]} MSE @{k}" for name in OPEN_LOOP_ERRORS for k in OPEN_LOOP_STEPS]
    rows = [header]
    for task in data.tasks:
        for method in data.methods:
            found = {name: data.lines[task][name].get(method) for name in OPEN_LOOP_ERRORS}
            first = found[OPEN_LOOP_ERRORS[0]]
            if first is None and not any(r.task == task and r.method == method
                                         for r in data.missing):
                continue  # no runs of this task and method
            steps = sorted(set(first.steps)) if first is not None else []
            step = ("—" if not steps else step_label(steps[0]) if len(steps) == 1
                    else f"{step_label(steps[0])}–{step_label(steps[-1])}")
            rows.append([task, method, step] + [cell(found[name], k) for name in OPEN_LOOP_ERRORS
                                                 for k in OPEN_LOOP_STEPS])
    text = markdown_table(rows)
    text += (f"\n\nMean ± std over seeds {when(data)}: the world model observes the first 15 "
             "steps of an evaluation episode, then imagines the next 35 under the episode's "
             "actions; the error of imagined step k is against episode step 15 + k - 1 "
             "(observations: the decoder's mean, per pixel value in [0, 1] or vector entry; "
             "rewards: the reward head's mean). Episodes shorter than 50 steps shorten both in "
             "the 15:35 ratio, so a step they do not reach reads —.")
    if data.missing:
        text += "\n\nMissing (no `open_loop.jsonl` line; agents without a world model write none):"
        text += "\n\n" + "\n".join(f"- {run_name(run)}: {data.why.get(run, '')}"
                                   for run in data.missing)
    return text
