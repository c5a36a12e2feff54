"""Reading the runs' files: scores, evaluation episodes, configs, JSON lines."""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.slot import config_difference
from experiments.spec import Run
from vsgjax.loop.rundir import CONFIG_FILE, EVAL_EPISODES_FILE, SCORES_FILE


class ReportWarning(UserWarning):
    """A problem in the run files that the report worked around (a skipped corrupt line...)."""


def warn(message: str, problems: list[str] | None) -> None:
    """Raise a :class:`ReportWarning` and append its message to ``problems``."""
    warnings.warn(message, ReportWarning, stacklevel=3)
    if problems is not None:
        problems.append(message)


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
                warn(f"{path}:{number}: skipped a corrupt line ({error.msg})", problems)
                continue
            if not isinstance(record, dict):
                warn(f"{path}:{number}: skipped a line that is not a JSON object", problems)
                continue
            records.append(record)
    return records


def is_number(value) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


@dataclass
class Curve:
    """One seed's evaluations: env steps, mean evaluation returns and, where the run recorded
    them, its wall seconds at each evaluation."""

    xs: np.ndarray
    ys: np.ndarray
    seed: str = ""
    wall: np.ndarray | None = None


def scores_record(record: dict, seed: str) -> Curve | None:
    """The curve of a ``{xs, ys[, wall_s]}`` record (its non-numbers dropped); None if it has
    none. ``wall_s`` is read only when every entry is a number beside a kept evaluation."""
    xs, ys = record.get("xs"), record.get("ys")
    if not isinstance(xs, list) or not isinstance(ys, list) or len(xs) != len(ys):
        return None
    walls = record.get("wall_s")
    if not isinstance(walls, list) or len(walls) != len(xs):
        walls = [None] * len(xs)
    rows = [(float(x), float(y), w) for x, y, w in zip(xs, ys, walls, strict=True)
            if is_number(x) and is_number(y)]
    wall = [w for _, _, w in rows]
    return Curve(np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), seed,
                 np.array(wall, dtype=float) if rows and all(map(is_number, wall)) else None)


def run_name(run: Run) -> str:
    return f"{run.task}/{run.method} s{run.seed}"


class RunRecords:
    """Reads (once) the scores of the runs under ``root``; collects the warnings it raised."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.problems: list[str] = []
        self._scores: dict[Run, Curve | None] = {}
        self._differs: dict[Run, str] = {}

    def differs(self, run: Run) -> str:
        """Why the run's log directory holds another run (its ``config.json`` is of another
        model, config or seed: ``launch --status`` shows it as ``config differs``); "" when it
        is the run's. A run that differs has no records here."""
        if run not in self._differs:
            self._differs[run] = "; ".join(config_difference(run, run.logdir(self.root)))
        return self._differs[run]

    def scores(self, run: Run) -> Curve | None:
        """The run's last valid ``scores.jsonl`` record (the file is rewritten at every
        evaluation), or, without one, the mean return per step of ``eval_episodes.jsonl``;
        None when neither has an evaluation or the directory holds another run."""
        if run not in self._scores:
            self._scores[run] = None if self.differs(run) else self._read_scores(run)
        return self._scores[run]

    def _read_scores(self, run: Run) -> Curve | None:
        logdir = run.logdir(self.root)
        path = logdir / SCORES_FILE
        if path.exists():
            for number, record in reversed(list(enumerate(read_jsonl(path, self.problems), 1))):
                curve = scores_record(record, str(run.seed))
                if curve is not None:
                    return curve if len(curve.xs) else None
                warn(f"{path}: record {number} has no valid xs/ys lists; skipped", self.problems)
        episodes = logdir / EVAL_EPISODES_FILE
        if episodes.exists():
            by_step: dict[float, list[float]] = {}
            for record in read_jsonl(episodes, self.problems):
                step, value = record.get("step"), record.get("return")
                if is_number(step) and is_number(value):
                    by_step.setdefault(float(step), []).append(float(value))
            if by_step:
                warn(f"{path} has no scores; rebuilt them from {episodes}", self.problems)
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
                warn(f"{path}: unreadable ({error!r}); using the experiment's config",
                     self.problems)
        env = run.config().env
        return env.action_repeat, env.time_limit
