"""What a job's files say about it (done, partial, new...), and the status table."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from experiments.launch.jobs import Job
from experiments.slot import config_difference
from experiments.spec import Run
from vsgjax.data import checkpoint
from vsgjax.loop.rundir import (
    CHECKPOINTS_DIR,
    METRICS_FILE,
    SCORES_FILE,
    RunDir,
)


@dataclass
class Status:
    """What a job's files say: ``state`` is one of

    * ``done``: finished (skipped by a launch);
    * ``partial``: a training run with a checkpoint short of its steps (a launch resumes it);
    * ``new``: nothing yet (a launch starts it);
    * ``results only``: evaluations short of its steps without a checkpoint to resume
      from (never launched: training would start over and replace them);
    * ``config differs``: a log directory of another config or seed (never launched or
      touched; ``experiments.report`` does not count it either);
    * ``damaged``: a ``scores.jsonl`` that cannot be read, or checkpoints none of which is
      intact (never launched: the note says what is wrong and what to do);
    * ``blocked``: an evaluate / rollouts job whose source run has not finished training.
    """

    state: str
    step: int | None = None  # latest env step (training) or the source checkpoint's step
    total: int | None = None  # train.steps of the run
    score: str = ""
    note: str = ""

    @property
    def launchable(self) -> bool:
        return self.state in ("partial", "new")


def checkpoint_step(logdir: Path) -> int | None:
    """Env step of the newest checkpoint of a training log directory (None if none)."""
    found = checkpoint.list_checkpoints(Path(logdir) / CHECKPOINTS_DIR)
    return found[-1][0] if found else None


def last_json_line(path: Path, tail_bytes: int = 65536) -> dict | None:
    """The last complete JSON line of ``path`` (read from its end; None if none)."""
    try:
        with open(path, "rb") as file:
            file.seek(0, os.SEEK_END)
            size = file.tell()
            file.seek(max(0, size - tail_bytes))
            lines = file.read().splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        try:
            record = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError):
            continue  # a line cut short by a running writer or a killed run
        if isinstance(record, dict):
            return record
    return None


def latest_score(logdir: Path) -> str:
    """The newest evaluation return of ``scores.jsonl``, as ``<return> @<env step>``."""
    record = last_json_line(Path(logdir) / SCORES_FILE)
    if not record or not record.get("ys"):
        return ""
    return f"{record['ys'][-1]:.3g} @{int(record['xs'][-1])}"


def latest_step(logdir: Path) -> int | None:
    """The newest env step a training run logged (``metrics.jsonl``) or checkpointed."""
    record = last_json_line(Path(logdir) / METRICS_FILE)
    steps = [s for s in (checkpoint_step(logdir), record and record.get("step")) if s is not None]
    return max(steps) if steps else None


def intact_checkpoint(logdir: Path) -> tuple[int | None, list[str]]:
    """(env step of the newest checkpoint whose header and CRC-32 are intact, None if none;
    ``name: why`` of each corrupt one newer than it). Reads newest first, stopping at the first
    intact one, as resuming does."""
    corrupt = []
    for step, path in reversed(checkpoint.list_checkpoints(Path(logdir) / CHECKPOINTS_DIR)):
        try:
            checkpoint.verify(path)
        except (checkpoint.CorruptCheckpointError, OSError) as error:
            corrupt.append(f"{path.name}: {error}")
            continue
        return step, corrupt
    return None, corrupt


def scores_problem(logdir: Path) -> str | None:
    """Why ``scores.jsonl`` cannot be read (a line that is not JSON, no ``xs``/``ys`` lists of
    one length); None when it is absent or readable."""
    path = Path(logdir) / SCORES_FILE
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as error:
        return f"{SCORES_FILE} unreadable ({error})"
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as error:
            return f"{SCORES_FILE} line {number} is not JSON ({error.msg})"
        xs, ys = (record.get("xs"), record.get("ys")) if isinstance(record, dict) else (0, 0)
        if not isinstance(xs, list) or not isinstance(ys, list) or len(xs) != len(ys):
            return f"{SCORES_FILE} line {number} has no xs/ys lists of one length"
    return None


RETRAIN = "vsgjax.train --restart trains it again (the old run is moved aside)"


def train_status(run: Run, logdir: Path) -> Status:
    """A training run's state from its log directory."""
    changed = config_difference(run, logdir)
    if changed:
        return Status("config differs", note="; ".join(changed))
    ckpt, corrupt = intact_checkpoint(logdir)
    step, score = latest_step(logdir), latest_score(logdir)
    if ckpt is None and corrupt:
        return Status("damaged", step, run.steps, score,
                      f"no intact checkpoint ({'; '.join(corrupt)}); {RETRAIN}")
    problem = scores_problem(logdir)
    if problem:
        return Status("damaged", step, run.steps, "", f"{problem}; restore it from a copy, "
                      f"or {RETRAIN}")
    skipped = f"corrupt: {'; '.join(corrupt)}" if corrupt else ""
    if ckpt is not None and ckpt >= run.steps:
        return Status("done", ckpt, run.steps, score, skipped)
    if ckpt is not None:
        return Status("partial", step, run.steps, score,
                      f"resumes from env step {ckpt}" + (f" ({skipped})" if skipped else ""))
    evaluated = RunDir(logdir).evaluated_without_checkpoint()
    if evaluated is not None:
        if evaluated >= run.steps:
            return Status("done", evaluated, run.steps, score, "its checkpoints are not here")
        return Status("results only", evaluated, run.steps, score,
                      "no checkpoint to resume from; vsgjax.train --restart "
                      "trains it again")
    return Status("new", step, run.steps, score)


def job_status(job: Job) -> Status:
    """What the files of ``job`` (and of its source run) say about it."""
    if job.kind == "train":
        return train_status(job.run, job.job_dir)
    source = train_status(job.run, job.source_dir)
    if source.state in ("config differs", "damaged"):
        return Status("blocked", note=f"source {job.source_dir}: {source.state}: {source.note}")
    if job.kind == "evaluate" and job.output.exists():
        return Status("done", source.step, score=_evaluation_score(job.output))
    if job.kind == "rollouts" and job.done_marker.exists():
        return Status("done", source.step)
    if source.state != "done":
        at = f"at env step {source.step} of {source.total}" if source.step else "not trained"
        return Status("blocked", source.step, note=f"source run {at}: {job.source_dir}")
    return Status("new", source.step, note=f"source checkpoint at env step {source.step}")


def _evaluation_score(path: Path) -> str:
    try:
        returns = [json.loads(line)["return"] for line in path.read_text().splitlines()]
    except (OSError, ValueError, KeyError):
        return "unreadable"
    returns = [r for r in returns if r is not None]
    return f"{sum(returns) / len(returns):.3g} ({len(returns)} ep)" if returns else ""


def _eta(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return ""
    seconds = int(seconds)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


def format_table(jobs: Sequence[Job], statuses: dict[int, Status], states: dict[int, str],
                 etas: dict[int, float | None] | None = None, limit: int | None = None) -> str:
    """One row per job: launch state, env steps, latest score, ETA and a note.

    ``states`` are the launcher's (running / failed ...) where it has one, else the files'.
    With ``limit`` rows at most, queued and finished jobs are summarised in one line.
    """
    etas = etas or {}
    header = ["#", "job", "state", "env steps", "score", "eta", "note"]
    rows = []
    for job in jobs:
        status = statuses[job.index]
        steps = "" if status.step is None else str(status.step)
        if status.total:
            steps = f"{steps or 0}/{status.total}"
        rows.append([str(job.index), job.name, states.get(job.index, status.state), steps,
                     status.score, _eta(etas.get(job.index)), status.note])
    counts: dict[str, int] = {}
    for row in rows:
        key = row[2] if row[2].startswith(("config", "results")) else row[2].split(" ")[0]
        counts[key] = counts.get(key, 0) + 1
    summary = ", ".join(f"{count} {state}" for state, count in counts.items())
    if limit is not None and len(rows) > limit:
        rows = [row for row in rows if row[2] not in ("queued", "done")][:limit]
    widths = [max(len(row[c]) for row in [header, *rows]) for c in range(len(header) - 1)]
    lines = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=False))
             + "  " + row[-1] for row in [header, *rows]]
    lines = [line.rstrip() for line in lines]
    lines.append(f"{jobs[0].experiment.name if jobs else ''}: {len(jobs)} jobs: {summary}")
    return "\n".join(lines)
