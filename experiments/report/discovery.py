"""The ``discovery_table`` (Table 1): the paper's discovery metrics beside ours, in env steps
(Markdown and LaTeX)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from experiments.report.context import Context
from experiments.report.reference import load_discovery_reference
from experiments.report.runs import is_number, read_jsonl, run_name, warn
from experiments.report.style import fmt, markdown_table
from experiments.spec import EVALUATION_FILE, Run

# Table 1's columns: (reference column, our episode key, heading, converted to env steps?).
DISCOVERY_COLUMNS = (
    ("first_visit_time", "discovery/mean_first_visit", "first-visit time", True),
    ("episode_length", "discovery/episode_length", "episode length", True),
    ("objects_not_visited_pct", "discovery/never_visited", "% objects not visited", False),
    ("visited_not_scored_pct", "discovery/visited_not_scored", "% visited not scored", False),
)


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
        name = experiment.reference[0] if experiment.reference else "vsg_paper_discovery.json"
        reference = load_discovery_reference(name, context.reference_dir)
    rows, missing, short = [], [], []
    for task in experiment.tasks:
        for method in experiment.methods:
            runs = context.runs_of(task, method)
            if not runs:
                continue
            columns: list[list[float]] = [[] for _ in DISCOVERY_COLUMNS]
            episodes = seeds = 0
            for run in runs:
                records = evaluation_episodes(context, run)
                if not records:
                    missing.append(run)
                    continue
                if experiment.episodes and len(records) < experiment.episodes:
                    short.append((run, len(records)))
                repeat, limit = context.records.env_units(run)
                seeds += 1
                episodes += len(records)
                for record in records:
                    for index, (name, key, _, steps) in enumerate(DISCOVERY_COLUMNS):
                        value = record.get(key)
                        if value is None and name == "episode_length":
                            value = record.get("length")
                        if not is_number(value):
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


def evaluation_episodes(context: Context, run: Run) -> list[dict]:
    """The episodes of the run's evaluation job (the latest checkpoint step if several)."""
    problems = context.records.problems
    path = context.experiment.job_dir(run, context.records.root) / EVALUATION_FILE
    if not path.exists():
        return []
    records = read_jsonl(path, problems)
    steps = {r.get("step") for r in records if is_number(r.get("step"))}
    if len(steps) > 1:
        last = max(steps)
        warn(f"{path}: episodes of {len(steps)} checkpoint steps; using the latest, {last:g}",
             problems)
        records = [r for r in records if r.get("step") == last]
    return records


def discovery_markdown(data: DiscoveryData) -> str:
    headings = [h for _, _, h, _ in DISCOVERY_COLUMNS]
    rows = [["task", "method", *[f"{h} ({s})" for h in headings for s in ("paper", "ours")],
             "episodes (seeds)"]]
    for row in data.rows:
        cells = []
        for index in range(len(DISCOVERY_COLUMNS)):
            cells.append(fmt(row.paper[index]) if row.paper else "—")
            cells.append(fmt(row.ours[index]) if row.episodes else "missing")
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
            cells.append(fmt(row.paper[index], nan="--") if row.paper else "--")
            cells.append(fmt(row.ours[index], nan="--") if row.episodes else "missing")
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


def discovery_text(data: DiscoveryData) -> str:
    """The report's paragraph under the table: how ours were counted, and the short runs."""
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
