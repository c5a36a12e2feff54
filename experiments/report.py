"""``python -m experiments.report NAME``: an experiment's figures and tables beside the paper's.

    python -m experiments.report bbs_basic                       # runs/bbs_basic/report/
    python -m experiments.report bbs_grid --root runs --out /tmp/grid
    python -m experiments.report bbs_basic --size debug --seeds 2 --steps 5000 --bin 1000

``--size``, ``--seeds``, ``--steps`` and ``--definitions`` are the launcher's: they select the
same runs (and so the same log directories) as the launch did. Every ``[[figures]]`` entry of
the experiment (``experiments/paper/<NAME>.toml``) becomes a PNG and a PDF (tables: Markdown,
and LaTeX for the discovery table) in the output directory, and ``report.md`` there links them
all. The manual is ``docs/reports.md``; in short:

* **curves**: one panel per task; our mean +- std over seeds on the paper's step grid, the
  paper's curve of the same method dashed in the same colour.
* **bars**: the score at each ``at`` step (nearest evaluation within one grid bin), ours vs paper.
* **grid**: arena size x distractors heatmaps of the score at each ``at``, ours beside the paper's.
* **discovery_table**: Table 1 (discovery metrics, in env steps), the paper's numbers beside ours.
* **summary**: the final score per task x method, and our distance from the paper's mean in
  units of the paper's seed std.
* **rollouts**: the images the rollouts jobs wrote.

Binning: the grid spacing is the reference curves' (100k env steps for BringBackShapes, 50k
for DMC; ``--bin`` overrides it; without reference data, or when the runs are shorter than
``FINE_GRID_BELOW`` reference bins (a ``--steps``-shortened debug version), the runs'
``train.eval_every``). An
evaluation at env step ``x`` falls into the bin of grid point ``spacing * ceil(x / spacing)``,
the nearest grid point at or after it; when a seed has several evaluations in one bin, the
latest (closest to the grid point) is its value there. Mean and std are over seeds (numpy's
population std, ``ddof=0``).

Every figure-building function returns its data (``curves_data``, ``bars_data``, ...) apart from
the drawing (``draw_curves``, ...): a run without scores is listed as missing in the data, in a
note on the figure and in ``report.md``; a corrupt line of a scores or episodes file is skipped
with a :class:`ReportWarning` naming the file and the line number.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import textwrap
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from experiments.spec import (  # noqa: E402
    DEFAULT_ROOT,
    EVALUATION_FILE,
    Experiment,
    ExperimentError,
    Run,
    add_selection_arguments,
    load_experiment,
)

REFERENCE_DIR = Path(__file__).resolve().parent / "reference_scores"
SCORES_FILE = "scores.jsonl"
EPISODES_FILE = "eval_episodes.jsonl"
CONFIG_FILE = "config.json"
FIGURE_FORMATS = ("png", "pdf")
# Method names of a reference file that differ from ours (the paper's names -> ours).
PAPER_METHODS = {"vsg_paper_bbs.json": {"VSGC": "VSG"}}
# Fixed colours, so a method looks the same in every figure; others cycle through tab10.
COLOURS = {"DreamerV1": "tab:gray", "DreamerV2": "tab:blue", "VSG": "tab:red",
           "SVSG": "tab:green", "SSM": "tab:purple"}
EXTRA_COLOURS = ("tab:orange", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")
# Table 1's columns: (reference column, our episode key, heading, converted to env steps?).
DISCOVERY_COLUMNS = (
    ("first_visit_time", "discovery/mean_first_visit", "first-visit time", True),
    ("episode_length", "discovery/episode_length", "episode length", True),
    ("objects_not_visited_pct", "discovery/never_visited", "% objects not visited", False),
    ("visited_not_scored_pct", "discovery/visited_not_scored", "% visited not scored", False),
)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".gif", ".svg", ".pdf", ".mp4")
INLINE_SUFFIXES = (".png", ".jpg", ".jpeg", ".gif", ".svg")
FIGURE_NOTE_RUNS = 6  # runs named in a figure's "missing" note before it says "and N more"
FINE_GRID_BELOW = 3  # runs shorter than this many reference bins use their eval grid


class ReportWarning(UserWarning):
    """A problem in the run files that the report worked around (a skipped corrupt line...)."""


# --- reading run files ----------------------------------------------------------------------


def read_jsonl(path: Path, problems: list[str] | None = None) -> list[dict]:
    """The JSON objects of ``path``, one a line; a line that is not a JSON object is skipped
    with a :class:`ReportWarning` ``"<path>:<line>: ..."`` (also appended to ``problems``)."""
    records = []
    with open(path, encoding="utf-8", errors="replace") as file:
        for number, line in enumerate(file, 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError as error:
                _warn(f"{path}:{number}: skipped a corrupt line ({error.msg})", problems)
                continue
            if not isinstance(record, dict):
                _warn(f"{path}:{number}: skipped a line that is not a JSON object", problems)
                continue
            records.append(record)
    return records


def _warn(message: str, problems: list[str] | None) -> None:
    warnings.warn(message, ReportWarning, stacklevel=3)
    if problems is not None:
        problems.append(message)


@dataclass
class Curve:
    """One seed's evaluations: env steps and mean evaluation returns."""

    xs: np.ndarray
    ys: np.ndarray
    seed: str = ""


class RunFiles:
    """Reads (once) the scores of the runs under ``root``; collects the warnings it raised."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.problems: list[str] = []
        self._scores: dict[Run, Curve | None] = {}

    def scores(self, run: Run) -> Curve | None:
        """The run's last valid ``scores.jsonl`` record (the file is rewritten at every
        evaluation), or, without one, the mean return per step of ``eval_episodes.jsonl``;
        None when neither has an evaluation."""
        if run not in self._scores:
            self._scores[run] = self._read_scores(run)
        return self._scores[run]

    def _read_scores(self, run: Run) -> Curve | None:
        logdir = run.logdir(self.root)
        path = logdir / SCORES_FILE
        if path.exists():
            for number, record in reversed(list(enumerate(read_jsonl(path, self.problems), 1))):
                curve = _scores_record(record, str(run.seed))
                if curve is not None:
                    return curve if len(curve.xs) else None
                _warn(f"{path}: record {number} has no valid xs/ys lists; skipped", self.problems)
        episodes = logdir / EPISODES_FILE
        if episodes.exists():
            by_step: dict[float, list[float]] = {}
            for record in read_jsonl(episodes, self.problems):
                step, value = record.get("step"), record.get("return")
                if _number(step) and _number(value):
                    by_step.setdefault(float(step), []).append(float(value))
            if by_step:
                _warn(f"{path} has no scores; rebuilt them from {episodes}", self.problems)
                steps = sorted(by_step)
                return Curve(np.array(steps), np.array([np.mean(by_step[s]) for s in steps]),
                             str(run.seed))
        return None

    def env_units(self, run: Run) -> tuple[int, int]:
        """(action repeat, time limit in env steps) of the run: its ``config.json``, else the
        config the experiment gives it."""
        path = run.logdir(self.root) / CONFIG_FILE
        if path.exists():
            try:
                env = json.loads(path.read_text())["env"]
                return int(env["action_repeat"]), int(env["time_limit"])
            except (ValueError, KeyError, TypeError) as error:
                _warn(f"{path}: unreadable ({error!r}); using the experiment's config",
                      self.problems)
        env = run.config().env
        return env.action_repeat, env.time_limit


def _number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _scores_record(record: dict, seed: str) -> Curve | None:
    xs, ys = record.get("xs"), record.get("ys")
    if not isinstance(xs, list) or not isinstance(ys, list) or len(xs) != len(ys):
        return None
    pairs = [(float(x), float(y)) for x, y in zip(xs, ys, strict=True)
             if _number(x) and _number(y)]
    return Curve(np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]), seed)


def run_name(run: Run) -> str:
    return f"{run.task}/{run.method} s{run.seed}"


# --- reference data -------------------------------------------------------------------------


def paper_task(task: str) -> str:
    """The reference files' name of our task: ``bbs_medium_d2`` ->
    ``bringbackshapes_sparse_distract2_size1.4``; DMC and other names are the same."""
    if task.startswith("bbs_"):
        import bbs

        if task in bbs.VARIANTS:
            kwargs = bbs.VARIANTS[task]
            return (f"bringbackshapes_sparse_distract{kwargs['num_distractors']}"
                    f"_size{kwargs['arena_scale']:.1f}")
    return task


@dataclass
class Reference:
    """A reference file of learning curves, in our task and method names."""

    name: str
    curves: dict[tuple[str, str], list[Curve]]  # (our task, our method) -> one Curve per seed
    paper_names: dict[tuple[str, str], tuple[str, str]]  # ours -> the file's (task, method)
    spacing: float  # the step grid of the curves

    @classmethod
    def from_records(cls, name: str, records: list[dict]) -> Reference:
        """From the file's records ``{task, method, seed, xs, ys}``."""
        methods = PAPER_METHODS.get(name, {})
        ours_of_task: dict[str, str] = {}
        curves: dict[tuple[str, str], list[Curve]] = {}
        names: dict[tuple[str, str], tuple[str, str]] = {}
        diffs = []
        for record in records:
            task, method = record["task"], record["method"]
            if task not in ours_of_task:
                ours_of_task[task] = _our_task(task)
            key = (ours_of_task[task], methods.get(method, method))
            curve = _scores_record(record, str(record.get("seed", "")))
            if curve is None or not len(curve.xs):
                continue
            curves.setdefault(key, []).append(curve)
            names[key] = (task, method)
            diffs.extend(np.diff(curve.xs).tolist())
        spacing = float(np.median(diffs)) if diffs else 0.0
        return cls(name, curves, names, spacing)

    def seeds(self, task: str, method: str) -> list[Curve]:
        return self.curves.get((task, method), [])


def _our_task(paper_name: str) -> str:
    if paper_name.startswith("bringbackshapes_"):
        import bbs

        for task in bbs.VARIANTS:
            if paper_task(task) == paper_name:
                return task
    return paper_name


def load_reference(name: str, directory: Path = REFERENCE_DIR) -> Reference:
    """The learning curves of ``directory/name`` (e.g. ``vsg_paper_bbs.json``)."""
    return Reference.from_records(name, json.loads((Path(directory) / name).read_text()))


def load_discovery_reference(name: str = "vsg_paper_discovery.json",
                             directory: Path = REFERENCE_DIR) -> dict:
    """Table 1: ``{"columns": [...], "values": {(task, method): [..]}, "source", "units"}``."""
    data = json.loads((Path(directory) / name).read_text())
    return {"columns": list(data["columns"]), "source": data.get("source", ""),
            "units": data.get("units", ""),
            "values": {(row["task"], row["method"]): [float(v) for v in row["values"]]
                       for row in data["rows"]}}


# --- binning --------------------------------------------------------------------------------


def bin_of(x: float, spacing: float) -> float:
    """The grid point whose bin holds an evaluation at env step ``x``: the nearest grid point
    at or after it, ``spacing * ceil(x / spacing)`` (0 -> 0, 1..spacing -> spacing, ...)."""
    return spacing * math.ceil(round(x / spacing, 9))


def binned(curve: Curve, spacing: float) -> dict[float, float]:
    """One seed on the grid: grid point -> the latest evaluation in its bin."""
    values: dict[float, tuple[float, float]] = {}
    for x, y in zip(curve.xs, curve.ys, strict=True):
        point = bin_of(float(x), spacing)
        if point not in values or x >= values[point][0]:
            values[point] = (float(x), float(y))
    return {point: y for point, (_, y) in sorted(values.items())}


def seed_stats(seeds: Iterable[dict[float, float]]) -> tuple[np.ndarray, ...]:
    """Per grid point over the seeds present there: (x, mean, std, number of seeds)."""
    seeds = list(seeds)
    points = sorted({p for seed in seeds for p in seed})
    columns = [[seed[p] for seed in seeds if p in seed] for p in points]
    return (np.array(points, dtype=float), np.array([np.mean(c) for c in columns]),
            np.array([np.std(c) for c in columns]), np.array([len(c) for c in columns]))


def value_near(curve: Curve, at: float, spacing: float) -> float | None:
    """The evaluation nearest to env step ``at`` and at most ``spacing`` away (ties: the
    earlier), or None."""
    if not len(curve.xs):
        return None
    distance = np.abs(curve.xs - at)
    index = int(np.argmin(distance))  # argmin takes the first, i.e. the earlier, of a tie
    return float(curve.ys[index]) if distance[index] <= spacing else None


@dataclass
class Stat:
    """Mean and std over seeds, and how many seeds."""

    mean: float = math.nan
    std: float = math.nan
    n: int = 0

    @classmethod
    def of(cls, values: Iterable[float | None]) -> Stat:
        values = [v for v in values if v is not None and math.isfinite(v)]
        if not values:
            return cls()
        return cls(float(np.mean(values)), float(np.std(values)), len(values))

    def text(self, digits: int = 2) -> str:
        if not self.n:
            return "missing"
        return f"{self.mean:.{digits}f} ± {self.std:.{digits}f} (n={self.n})"


# --- the report's context -------------------------------------------------------------------


@dataclass
class Context:
    """What every figure needs: the experiment, its runs' files, the reference, the grid."""

    experiment: Experiment
    files: RunFiles
    reference: Reference | None
    spacing: float
    reference_dir: Path = REFERENCE_DIR

    @classmethod
    def create(cls, experiment: Experiment, root: Path, reference_dir: Path = REFERENCE_DIR,
               spacing: float | None = None) -> Context:
        reference = None
        name = experiment.reference
        if name and experiment.kind == "train":
            reference = load_reference(name, reference_dir)
        steps = max((run.steps for run in experiment.runs), default=0)
        if spacing is None:
            if reference is not None and steps >= FINE_GRID_BELOW * reference.spacing > 0:
                spacing = reference.spacing
            elif experiment.runs:
                spacing = float(experiment.runs[0].config().train.eval_every)
            else:
                spacing = 1.0
        return cls(experiment, RunFiles(root), reference, float(spacing), Path(reference_dir))

    @property
    def steps(self) -> int:
        return max((run.steps for run in self.experiment.runs), default=0)

    def runs_of(self, task: str, method: str) -> list[Run]:
        return [r for r in self.experiment.runs if r.task == task and r.method == method]

    def ours(self, task: str, method: str) -> tuple[list[Curve], list[Run]]:
        """Our seeds of task x method that have scores, and the runs that have none."""
        curves, missing = [], []
        for run in self.runs_of(task, method):
            curve = self.files.scores(run)
            if curve is None:
                missing.append(run)
            else:
                curves.append(curve)
        return curves, missing

    def paper(self, task: str, method: str) -> list[Curve]:
        return self.reference.seeds(task, method) if self.reference is not None else []

    def missing_runs(self) -> list[Run]:
        return [run for run in self.experiment.runs if self.files.scores(run) is None]


def colour(method: str, methods: list[str]) -> str:
    if method in COLOURS:
        return COLOURS[method]
    others = [m for m in methods if m not in COLOURS]
    return EXTRA_COLOURS[others.index(method) % len(EXTRA_COLOURS)] if method in others \
        else "black"


def step_label(step: float) -> str:
    """1_000_000 -> "1M", 2_500_000 -> "2.5M", 50_000 -> "50k"."""
    for scale, suffix in ((1e6, "M"), (1e3, "k")):
        if abs(step) >= scale:
            return f"{step / scale:g}{suffix}"
    return f"{step:g}"


def missing_note(runs: list[Run], limit: int = FIGURE_NOTE_RUNS, width: int = 0,
                 with_task: bool = True) -> str:
    """``"missing: bbs_basic/VSG s1, ..."`` for a figure (empty when nothing is missing),
    wrapped to lines of ``width`` characters if ``width``."""
    if not runs:
        return ""
    names = [run_name(run) if with_task else f"{run.method} s{run.seed}" for run in runs[:limit]]
    more = f" and {len(runs) - limit} more (see report.md)" if len(runs) > limit else ""
    note = "missing: " + ", ".join(names) + more
    return textwrap.fill(note, width) if width else note


def save_figure(figure: Figure, stem: Path) -> list[Path]:
    """``stem``.png and ``stem``.pdf."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for suffix in FIGURE_FORMATS:
        path = stem.with_suffix(f".{suffix}")
        metadata = {"CreationDate": None} if suffix == "pdf" else {"Software": None}
        figure.savefig(path, dpi=120, metadata=metadata)
        paths.append(path)
    return paths


def _panel_grid(count: int, max_columns: int = 4) -> tuple[int, int]:
    columns = min(max_columns, max(count, 1))
    return -(-max(count, 1) // columns), columns


# --- curves ---------------------------------------------------------------------------------


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
    rows, columns = _panel_grid(len(data.tasks))
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
        note = missing_note([r for r in data.missing if r.task == task], 4, 45, False)
        if note:
            ax.text(0.02, 0.98, note, transform=ax.transAxes, va="top", fontsize=6,
                    color="firebrick")
        if not data.lines[task]:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", color="gray")
        ax.set_title(task, fontsize=9)
        ax.set_xlabel("env steps", fontsize=8)
        ax.set_ylabel("eval return", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(
            lambda value, _: step_label(value)))
        ax.grid(alpha=0.3)
    for index in range(len(data.tasks), rows * columns):
        axes[index // columns][index % columns].set_visible(False)
    if handles:
        figure.legend(list(handles.values()), list(handles), loc="outside lower center",
                      ncols=min(len(handles), 6 if columns > 1 else 3), fontsize=8)
    figure.suptitle(title or f"learning curves (mean ± std over seeds, bins of "
                    f"{step_label(data.spacing)} steps)", fontsize=10)
    return save_figure(figure, stem)


# --- bars -----------------------------------------------------------------------------------


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
            missing.extend(r for r in runs if context.files.scores(r) is None)
            paper = context.paper(task, method)
            for step in at:
                ours = []
                for run in runs:
                    curve = context.files.scores(run)
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
    rows, columns = _panel_grid(len(panels))
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
    for index in range(len(panels), rows * columns):
        axes[index // columns][index % columns].set_visible(False)
    from matplotlib.patches import Patch

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


# --- grid (Fig. 3c) -------------------------------------------------------------------------


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
    import bbs

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
                    cells.append(f"{_fmt(ours)} / {_fmt(paper)}")
                rows.append([f"{scale:g}", *cells])
            parts.append(f"{method} at {step_label(step)} (ours / paper):\n\n"
                         + markdown_table(rows))
    return "\n\n".join(parts)


# --- discovery table (Table 1) --------------------------------------------------------------


@dataclass
class DiscoveryRow:
    task: str
    method: str
    paper: list[float] | None  # the reference's values (None: not in the table)
    ours: list[float]  # means over episodes and seeds, env steps for the step columns
    episodes: int
    seeds: int


@dataclass
class DiscoveryData:
    columns: list[str]
    rows: list[DiscoveryRow]
    missing: list[Run]  # runs without an evaluation file (or without episodes)
    short: list[tuple[Run, int]]  # runs with fewer episodes than the experiment asks
    episodes: int  # episodes per run the experiment asks for (0: its default)
    source: str
    units: str


def discovery_data(context: Context, reference: dict | None = None) -> DiscoveryData:
    """Table 1: per task x method, the paper's values and the mean of ours over all episodes
    of all seeds (the ``evaluation.jsonl`` of each evaluate job). Our first-visit time and
    episode length are counted in agent steps; they are converted to env steps (x the run's
    action repeat; the episode length capped at the time limit, the paper's maximum)."""
    experiment = context.experiment
    if reference is None:
        reference = load_discovery_reference(experiment.reference or "vsg_paper_discovery.json",
                                             context.reference_dir)
    rows, missing, short = [], [], []
    for task in experiment.tasks:
        for method in experiment.methods:
            runs = context.runs_of(task, method)
            if not runs:
                continue
            columns: list[list[float]] = [[] for _ in DISCOVERY_COLUMNS]
            episodes = seeds = 0
            for run in runs:
                records = _evaluation_episodes(context, run)
                if not records:
                    missing.append(run)
                    continue
                if experiment.episodes and len(records) < experiment.episodes:
                    short.append((run, len(records)))
                repeat, limit = context.files.env_units(run)
                seeds += 1
                episodes += len(records)
                for record in records:
                    for index, (name, key, _, steps) in enumerate(DISCOVERY_COLUMNS):
                        value = record.get(key)
                        if value is None and name == "episode_length":
                            value = record.get("length")
                        if not _number(value):
                            continue  # e.g. first visit of an episode that visited nothing
                        value = float(value)
                        if steps:
                            value *= repeat
                            if name == "episode_length":
                                value = min(value, float(limit))
                        columns[index].append(value)
            ours = [float(np.mean(c)) if c else math.nan for c in columns]
            rows.append(DiscoveryRow(task, method, reference["values"].get((task, method)),
                                     ours, episodes, seeds))
    return DiscoveryData(reference["columns"], rows, missing, short, experiment.episodes,
                         reference["source"], reference["units"])


def _evaluation_episodes(context: Context, run: Run) -> list[dict]:
    """The episodes of the run's evaluation job (the latest checkpoint step if several)."""
    path = context.experiment.job_dir(run, context.files.root) / EVALUATION_FILE
    if not path.exists():
        return []
    records = read_jsonl(path, context.files.problems)
    steps = {r.get("step") for r in records if _number(r.get("step"))}
    if len(steps) > 1:
        last = max(steps)
        _warn(f"{path}: episodes of {len(steps)} checkpoint steps; using the latest, "
              f"{last:g}", context.files.problems)
        records = [r for r in records if r.get("step") == last]
    return records


def discovery_markdown(data: DiscoveryData) -> str:
    headings = [h for _, _, h, _ in DISCOVERY_COLUMNS]
    rows = [["task", "method", *[f"{h} ({s})" for h in headings for s in ("paper", "ours")],
             "episodes (seeds)"]]
    for row in data.rows:
        cells = []
        for index in range(len(DISCOVERY_COLUMNS)):
            cells.append(_fmt(row.paper[index]) if row.paper else "—")
            cells.append(_fmt(row.ours[index]) if row.episodes else "missing")
        rows.append([row.task, row.method, *cells, f"{row.episodes} ({row.seeds})"])
    return markdown_table(rows)


def discovery_latex(data: DiscoveryData) -> str:
    headings = [h.replace("%", r"\%") for _, _, h, _ in DISCOVERY_COLUMNS]
    lines = [r"\begin{table}[t]", r"\centering", r"\small",
             r"\begin{tabular}{ll" + "rr" * len(headings) + "r}", r"\toprule",
             " & & " + " & ".join(rf"\multicolumn{{2}}{{c}}{{{h}}}" for h in headings)
             + r" & \\",
             "task & method & " + " & ".join(["paper & ours"] * len(headings))
             + r" & episodes \\", r"\midrule"]
    previous = None
    for row in data.rows:
        if previous is not None and row.task != previous:
            lines.append(r"\midrule")
        cells = []
        for index in range(len(DISCOVERY_COLUMNS)):
            cells.append(_fmt(row.paper[index], nan="--") if row.paper else "--")
            cells.append(_fmt(row.ours[index], nan="--") if row.episodes else "missing")
        task = row.task.replace("_", r"\_") if row.task != previous else ""
        lines.append(f"{task} & {row.method} & " + " & ".join(cells) + f" & {row.episodes}"
                     + r" \\")
        previous = row.task
    lines += [r"\bottomrule", r"\end{tabular}",
              r"\caption{Discovery metrics: the paper's Table 1 beside ours (mean over "
              r"episodes and seeds; first-visit time and episode length in environment steps, "
              r"action repeat counted, maximum 3000).}",
              r"\end{table}"]
    return "\n".join(lines) + "\n"


# --- summary --------------------------------------------------------------------------------


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


def std_units(ours: float, paper_mean: float, paper_std: float) -> float:
    """How many of the paper's seed stds ours lies above (positive) or below its mean."""
    difference = ours - paper_mean
    if paper_std > 0:
        return difference / paper_std
    return 0.0 if difference == 0 else math.copysign(math.inf, difference)


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
                     else "no reference", _fmt(row.difference)])
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


# --- rollouts -------------------------------------------------------------------------------


@dataclass
class RolloutsData:
    images: dict[Run, list[Path]]  # run -> files its rollouts job wrote (sorted)
    missing: list[Run]  # rollouts jobs that wrote no image


def rollouts_data(context: Context) -> RolloutsData:
    images, missing = {}, []
    for run in context.experiment.runs:
        directory = context.experiment.job_dir(run, context.files.root)
        found = sorted(p for p in directory.rglob("*") if p.is_file()
                       and p.suffix.lower() in IMAGE_SUFFIXES) if directory.is_dir() else []
        if found:
            images[run] = found
        else:
            missing.append(run)
    return RolloutsData(images, missing)


def rollouts_markdown(data: RolloutsData, out: Path) -> str:
    parts = []
    for run, paths in data.images.items():
        parts.append(f"### {run_name(run)}\n")
        for path in paths:
            link = _relative(path, out)
            if path.suffix.lower() in INLINE_SUFFIXES:
                parts.append(f"![{path.name}]({link})\n")
            else:
                parts.append(f"- [{path.name}]({link})\n")
    return "\n".join(parts) if parts else "No rollout images found."


# --- the report -----------------------------------------------------------------------------


@dataclass
class Section:
    kind: str
    name: str
    data: object
    files: list[Path] = field(default_factory=list)
    markdown: str = ""


@dataclass
class Report:
    experiment: Experiment
    out: Path
    sections: list[Section]
    missing: list[Run]
    problems: list[str]
    markdown: Path


def build_report(experiment: Experiment, root: Path = DEFAULT_ROOT, out: Path | None = None,
                 reference_dir: Path = REFERENCE_DIR, spacing: float | None = None) -> Report:
    """Every figure of ``experiment`` into ``out`` (default ``root/<name>/report``), and
    ``report.md`` linking them."""
    out = Path(out) if out is not None else Path(root) / experiment.name / "report"
    out.mkdir(parents=True, exist_ok=True)
    context = Context.create(experiment, root, reference_dir, spacing)
    names = [figure.get("kind", "?") for figure in experiment.figures]
    sections = []
    for index, figure in enumerate(experiment.figures):
        kind = figure.get("kind", "?")
        name = kind if names.count(kind) == 1 else f"{kind}{index}"
        sections.append(_section(context, kind, name, figure, out))
    if experiment.kind == "train":
        missing = context.missing_runs()
    else:
        missing = list(dict.fromkeys(run for s in sections for run in _missing_of(s.data)))
    report = Report(experiment, out, sections, missing, context.files.problems,
                    out / "report.md")
    report.markdown.write_text(_report_markdown(report, context, Path(root)))
    return report


def _missing_of(data) -> list[Run]:
    return list(getattr(data, "missing", []))


def _section(context: Context, kind: str, name: str, figure: dict, out: Path) -> Section:
    stem = out / name
    if kind == "curves":
        data = curves_data(context)
        return Section(kind, name, data, draw_curves(data, stem), _curves_text(data))
    if kind == "bars":
        data = bars_data(context, figure.get("at", ()))
        return Section(kind, name, data, draw_bars(data, stem), bars_markdown(data))
    if kind == "grid":
        data = grid_data(context, figure.get("at", ()))
        return Section(kind, name, data, draw_grid(data, stem), grid_markdown(data))
    if kind == "discovery_table":
        data = discovery_data(context)
        table = discovery_markdown(data)
        files = [stem.with_suffix(".md"), stem.with_suffix(".tex")]
        files[0].write_text(table + "\n")
        files[1].write_text(discovery_latex(data))
        return Section(kind, name, data, files, table + "\n\n" + _discovery_text(data))
    if kind == "summary":
        data = summary_data(context)
        files = draw_summary(data, stem, context.experiment.methods)
        return Section(kind, name, data, files, summary_markdown(data))
    if kind == "rollouts":
        data = rollouts_data(context)
        return Section(kind, name, data, [], rollouts_markdown(data, out))
    _warn(f"figure kind {kind!r} is not known to experiments.report; skipped",
          context.files.problems)
    return Section(kind, name, None, [], f"Unknown figure kind {kind!r}: not drawn.")


def _curves_text(data: CurvesData) -> str:
    drawn = sorted({f"{m} ({pm} in the file)" if pm != m else m
                    for _, m, _, pm in data.reference_drawn})
    text = (f"Mean ± std over seeds, binned on a grid of {step_label(data.spacing)} env steps "
            "(an evaluation counts at the nearest grid point at or after it; a seed's latest "
            "evaluation in a bin is its value). Dashed: the paper's curve of the same method.")
    return text + (f" Reference curves drawn: {', '.join(drawn)}." if drawn
                   else " No reference curves for these methods.")


def _discovery_text(data: DiscoveryData) -> str:
    lines = ["Ours: mean over all evaluation episodes of all seeds (the paper: 50 episodes x "
             "5 seeds). First-visit time and episode length are in env steps, action repeat "
             "counted: our agent-step counts x the run's action repeat, the episode length "
             "capped at the time limit (the paper's maximum, 3000); an episode that visited no "
             "object has no first-visit time and is left out of that column. "
             f"Paper: {data.source}"]
    if data.short:
        lines.append("")
        lines.append(f"Runs with fewer episodes than the experiment's {data.episodes}: "
                     + ", ".join(f"{run_name(run)} ({count})" for run, count in data.short)
                     + ".")
    return "\n".join(lines)


def _report_markdown(report: Report, context: Context, root: Path) -> str:
    experiment = report.experiment
    runs = experiment.runs
    first = runs[0] if runs else None
    lines = [f"# {experiment.name}", "", experiment.description, ""]
    seeds = sorted({run.seed for run in runs})
    settings = (f"{len(runs)} (tasks: {len(experiment.tasks)}, methods: "
                f"{len(experiment.methods)}, seeds: {len(seeds)}), size `{first.size}`, "
                f"train.steps {first.steps}" if first else "none")
    lines += [f"- runs: {settings}; root `{root}`"]
    if experiment.kind == "evaluate":
        lines.append(f"- evaluates the trained runs of experiment `{experiment.source}` "
                     f"({experiment.episodes or 'the default number of'} episodes each)")
    elif experiment.kind == "rollouts":
        lines.append(f"- draws from the trained runs of experiment `{experiment.source}`")
    if experiment.reference:
        lines.append(f"- reference: `experiments/reference_scores/{experiment.reference}` "
                     "(see `experiments/reference_scores/PROVENANCE.md`)")
    else:
        lines.append("- reference: none (no paper data in `experiments/reference_scores/`)")
    if context.reference is not None:
        lines.append(f"- grid: {step_label(context.spacing)} env steps")
    lines.append("")
    lines += ["## Missing runs", ""]
    if report.missing:
        lines.append(f"{len(report.missing)} of {len(runs)} runs have no results:")
        lines.append("")
        for run in report.missing:
            where = (run.logdir(root) / SCORES_FILE if experiment.kind == "train"
                     else experiment.job_dir(run, root))
            lines.append(f"- {run_name(run)}: `{where}`")
    else:
        lines.append("None: every run has results.")
    lines.append("")
    incomplete = _incomplete_runs(context) if experiment.kind == "train" else []
    if incomplete:
        lines += ["## Incomplete runs", "",
                  "Runs whose last evaluation is more than one grid bin before train.steps "
                  "(their seeds thin out the end of the curves):", ""]
        lines += [f"- {run_name(run)}: last evaluation at env step {last:g} of {run.steps}"
                  for run, last in incomplete]
        lines.append("")
    if report.problems:
        lines += ["## Warnings", ""] + [f"- {p}" for p in report.problems] + [""]
    for section in report.sections:
        lines += [f"## {section.name}", ""]
        for path in section.files:
            link = _relative(path, report.out)
            if path.suffix == ".png":
                lines += [f"![{section.name}]({link})", ""]
        links = [f"[{p.suffix[1:].upper()}]({_relative(p, report.out)})" for p in section.files]
        if links:
            lines += ["Files: " + ", ".join(links), ""]
        if section.markdown:
            lines += [section.markdown, ""]
    return "\n".join(lines)


def _incomplete_runs(context: Context) -> list[tuple[Run, float]]:
    found = []
    for run in context.experiment.runs:
        curve = context.files.scores(run)
        if curve is not None and float(curve.xs.max()) < run.steps - context.spacing:
            found.append((run, float(curve.xs.max())))
    return found


# --- helpers --------------------------------------------------------------------------------


def markdown_table(rows: list[list[str]]) -> str:
    header, *body = rows
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in body]
    return "\n".join(lines)


def _fmt(value: float | None, digits: int = 2, nan: str = "—") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return nan
    if math.isinf(value):
        return "∞" if value > 0 else "−∞"
    return f"{value:.{digits}f}"


def _relative(path: Path, start: Path) -> str:
    import os

    return Path(os.path.relpath(path.resolve(), start.resolve())).as_posix()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.report",
                                     description=__doc__.split("\n")[0])
    add_selection_arguments(parser)  # the launch's options find the launch's runs
    parser.add_argument("--out", type=Path, default=None,
                        help="output directory (default: ROOT/NAME/report)")
    parser.add_argument("--bin", type=float, default=None,
                        help="grid spacing in env steps (default: the reference's grid)")
    args = parser.parse_args(argv)
    if args.bin is not None and args.bin <= 0:
        parser.error(f"--bin must be positive, got {args.bin:g}")
    try:
        experiment = load_experiment(args.name, args.size, args.seeds, args.steps,
                                     args.definitions)
    except ExperimentError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    report = build_report(experiment, args.root, args.out, spacing=args.bin)
    print(f"{report.markdown}: {len(report.sections)} figures, "
          f"{len(report.missing)} of {len(experiment.runs)} runs missing, "
          f"{len(report.problems)} warnings")
    return 0


if __name__ == "__main__":
    sys.exit(main())
