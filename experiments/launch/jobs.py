"""An experiment's jobs: one command per run (train it, evaluate it, or draw its rollouts), and
the processes that run them (several seeds of one training configuration may share one)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from experiments.spec import EVALUATION_FILE, Experiment, Run

REPO = Path(__file__).resolve().parents[2]  # the directory every job runs in
LOG_FILE = "launch.log"  # a job's stdout and stderr, appended by every launch
DONE_FILE = "launch.done"  # written when a rollouts job exits 0 (its "finished" marker)


class LaunchError(ValueError):
    """Bad launcher input; the message names the value and lists the valid ones."""


@dataclass(frozen=True)
class Job:
    """One command of an experiment: train a run, evaluate it, or draw its rollouts."""

    index: int
    experiment: Experiment
    run: Run
    root: Path

    @property
    def kind(self) -> str:
        return self.experiment.kind

    @property
    def name(self) -> str:
        return f"{self.run.task}/{self.run.method_dir}/s{self.run.seed}"

    @property
    def job_dir(self) -> Path:
        return self.experiment.job_dir(self.run, self.root)

    @property
    def source_dir(self) -> Path:
        """The training run's log directory (the job's own for a training job)."""
        return self.run.logdir(self.root)

    @property
    def output(self) -> Path | None:
        """The file whose existence means an evaluate job is finished."""
        return self.job_dir / EVALUATION_FILE if self.kind == "evaluate" else None

    @property
    def log(self) -> Path:
        return self.job_dir / LOG_FILE

    @property
    def done_marker(self) -> Path | None:
        return self.job_dir / DONE_FILE if self.kind == "rollouts" else None

    def command(self, python: str = sys.executable) -> list[str]:
        if self.kind == "train":
            return self.run.train_command(self.root, python)
        if self.kind == "evaluate":
            return [python, "-m", "vsgjax.evaluate", str(self.source_dir), "--episodes",
                    str(self.experiment.episodes), "--output", str(self.output)]
        return [python, "-m", "experiments.rollouts", str(self.source_dir), "--out",
                str(self.job_dir)]


@dataclass(frozen=True)
class Process:
    """The jobs one process runs: one job, or seeds of one task, method and config that train
    in lockstep (``vsgjax.train --seeds``), spread over ``devices`` host devices if above 1."""

    jobs: tuple[Job, ...]
    devices: int = 1

    @property
    def leader(self) -> Job:
        """The job whose directory holds the process's log."""
        return self.jobs[0]

    @property
    def name(self) -> str:
        if len(self.jobs) == 1:
            return self.leader.name
        seeds = ",".join(str(job.run.seed) for job in self.jobs)
        return f"{self.leader.run.task}/{self.leader.run.method_dir}/s{{{seeds}}}"

    def command(self, python: str = sys.executable) -> list[str]:
        if len(self.jobs) == 1:
            return self.leader.command(python)
        seeds = [job.run.seed for job in self.jobs]
        command = self.leader.run.train_command(self.leader.root, python, seeds)
        return command + ([f"train.devices={self.devices}"] if self.devices > 1 else [])

    def env(self, base: dict[str, str]) -> dict[str, str]:
        """``base`` with ``devices`` forced host devices (XLA_FLAGS) where it spreads seeds."""
        if self.devices == 1:
            return base
        flags = f"{base.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={self.devices}"
        return dict(base, XLA_FLAGS=flags.strip())


def next_to_start(queue: Sequence[Process], free_devices: int, idle: bool) -> int | None:
    """The index in ``queue`` of the first process whose ``devices`` fit in ``free_devices``,
    or None. A process too large for now waits while a later, smaller one takes the room, so
    that two single seeds train side by side on the cores one pair of seeds would use; on an
    ``idle`` machine the first process starts whatever its size."""
    if idle and queue:
        return 0
    return next((index for index, process in enumerate(queue)
                 if process.devices <= free_devices), None)


def group_processes(jobs: Sequence[Job], seeds_per_process: int, spread: bool,
                    resume_step: Callable[[Job], int | None]) -> list[Process]:
    """``jobs`` as processes, in order: training jobs of one task, method and config that
    resume from the same checkpoint step (``resume_step``; None: a new run) in groups of up to
    ``seeds_per_process`` (the seeds of one process train in lockstep); every other job alone.
    With ``spread``, a group's seeds go one to a forced host device."""
    groups: list[list[Job]] = []
    open_group: dict[tuple, list[Job]] = {}
    for job in jobs:
        if job.kind != "train":
            groups.append([job])
            continue
        run = job.run
        key = (run.task, run.model, run.variant, run.size, run.steps, run.overrides,
               resume_step(job))
        group = open_group.get(key)
        if group is None or len(group) >= seeds_per_process:
            group = open_group[key] = []
            groups.append(group)
        group.append(job)
    return [Process(tuple(group), len(group) if spread and len(group) > 1 else 1)
            for group in groups]


def make_jobs(experiment: Experiment, root: Path, tasks: Sequence[str] = (),
              models: Sequence[str] = ()) -> list[Job]:
    """The experiment's jobs, optionally only those of some tasks / models (``--task/--model``)."""
    for what, wanted, valid in (("task", tasks, experiment.tasks),
                                ("model", models, _models(experiment))):
        unknown = [value for value in wanted if value not in valid]
        if unknown:
            raise LaunchError(f"unknown {what} {unknown[0]!r} for experiment "
                              f"{experiment.name!r}; valid: {', '.join(valid)}")
    runs = [run for run in experiment.runs if (not tasks or run.task in tasks)
            and (not models or run.model in models or run.method_dir in models)]
    return [Job(index, experiment, run, Path(root)) for index, run in enumerate(runs)]


def _models(experiment: Experiment) -> list[str]:
    """Model names and model-variant names (``vsg-nosparsity``) a ``--model`` may name."""
    names = [run.model for run in experiment.runs] + [run.method_dir for run in experiment.runs]
    return list(dict.fromkeys(names))
