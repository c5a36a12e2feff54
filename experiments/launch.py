"""Launch an experiment's runs: ``python -m experiments.launch NAME [options]``.

    python -m experiments.launch bbs_basic --size debug --seeds 2 --steps 5000 --jobs 2
    python -m experiments.launch bbs_grid --backend slurm --partition gpu --time 1440
    python -m experiments.launch bbs_grid --backend print      # commands.txt + sbatch.sh
    python -m experiments.launch bbs_grid --status             # the table only

The experiment (``experiments/paper/NAME.toml``, see :mod:`experiments.spec`) expands into one
job per run: ``python -m vsgjax.train`` for a training experiment, ``python -m vsgjax.evaluate
<source run> --output <job dir>/evaluation.jsonl`` for an evaluate experiment and
``python -m experiments.rollouts <source run> --out <job dir>`` for a rollouts one.

Backends: ``local`` runs ``--jobs`` subprocesses at a time with a live status table; ``slurm``
submits a job array through submitit, requeued on timeout or preemption; ``print`` writes the
commands and an sbatch array script for clusters without Python on the login node.

Relaunching the same command skips what is finished (a training run whose newest checkpoint
reached its ``train.steps``, an evaluation whose output file exists, a rollouts job with its
``launch.done`` marker) and reruns the rest, which resume from their checkpoints. A log
directory whose ``config.json`` holds another model or env config is reported as "config
differs" and left alone. Every job appends its output to ``<job dir>/launch.log``.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from experiments.spec import (
    EVALUATION_FILE,
    PAPER_DIR,
    Experiment,
    ExperimentError,
    Run,
    add_selection_arguments,
    experiment_names,
    load_experiment,
)
from vsgjax import checkpoint
from vsgjax.config import config_changes, to_dict
from vsgjax.host import allocator_env

try:  # the slurm backend's requeueable job needs submitit (the "slurm" extra)
    from submitit.helpers import Checkpointable as _Checkpointable
except ImportError:  # pragma: no cover - depends on the environment
    _Checkpointable = object

REPO = Path(__file__).resolve().parents[1]
BACKENDS = ("local", "slurm", "print")
LOG_FILE = "launch.log"  # a job's stdout and stderr, appended by every launch
DONE_FILE = "launch.done"  # written when a rollouts job exits 0 (its "finished" marker)
COMMANDS_FILE = "commands.txt"
SBATCH_FILE = "sbatch.sh"
SUBMITIT_DIR = ".submitit"
INSTALL_SLURM = 'the slurm backend needs submitit: pip install -e ".[slurm]"'
STOP_TIMEOUT_S = 600  # how long a stopped job may take to save its checkpoint


class LaunchError(ValueError):
    """Bad launcher input; the message names the value and lists the valid ones."""


# --- jobs and their state on disk --------------------------------------------------------------


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


@dataclass
class Status:
    """What a job's files say: ``state`` is one of

    * ``done``: finished (skipped by a launch);
    * ``partial``: a training run with a checkpoint short of its steps (a launch resumes it);
    * ``new``: nothing yet (a launch starts it);
    * ``config differs``: a log directory of another config (never launched or touched);
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
    found = checkpoint.list_checkpoints(Path(logdir) / "checkpoints")
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
    record = last_json_line(Path(logdir) / "scores.jsonl")
    if not record or not record.get("ys"):
        return ""
    return f"{record['ys'][-1]:.3g} @{int(record['xs'][-1])}"


def latest_step(logdir: Path) -> int | None:
    """The newest env step a training run logged (``metrics.jsonl``) or checkpointed."""
    record = last_json_line(Path(logdir) / "metrics.jsonl")
    steps = [s for s in (checkpoint_step(logdir), record and record.get("step")) if s is not None]
    return max(steps) if steps else None


def config_difference(run: Run, logdir: Path) -> list[str]:
    """The keys (outside ``train``) where ``logdir/config.json`` differs from ``run.config()``,
    as ``section.key: saved -> wanted``; [] when there is no config.json or it agrees."""
    path = Path(logdir) / "config.json"
    if not path.exists():
        return []
    try:
        saved = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        return [f"config.json unreadable ({error})"]
    return config_changes(saved, _wanted_config(run))


@functools.cache
def _wanted_config(run: Run) -> dict:
    return to_dict(run.config())


def train_status(run: Run, logdir: Path) -> Status:
    """A training run's state from its log directory."""
    changed = config_difference(run, logdir)
    if changed:
        return Status("config differs", note="; ".join(changed))
    ckpt = checkpoint_step(logdir)
    step, score = latest_step(logdir), latest_score(logdir)
    if ckpt is not None and ckpt >= run.steps:
        return Status("done", ckpt, run.steps, score)
    if ckpt is not None:
        return Status("partial", step, run.steps, score, f"resumes from env step {ckpt}")
    return Status("new", step, run.steps, score)


def job_status(job: Job) -> Status:
    """What the files of ``job`` (and of its source run) say about it."""
    if job.kind == "train":
        return train_status(job.run, job.job_dir)
    source = train_status(job.run, job.source_dir)
    if source.state == "config differs":
        return Status("blocked", note=f"source {job.source_dir}: config differs: {source.note}")
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


# --- the status table --------------------------------------------------------------------------


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
        key = row[2].split(" ")[0] if not row[2].startswith("config") else row[2]
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


# --- running a job's process -------------------------------------------------------------------


def job_env(parallel: int = 1) -> dict[str, str]:
    """The environment of a job's process: the launcher's, unbuffered output, the host
    allocator of :mod:`vsgjax.host` and, with several jobs per machine, a share of the GPU."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    if "LD_PRELOAD" not in env:
        env.update(allocator_env())
    if parallel > 1 and not {"XLA_PYTHON_CLIENT_MEM_FRACTION",
                             "XLA_PYTHON_CLIENT_PREALLOCATE"} & set(env):
        env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{0.9 / parallel:.3f}"
    return env


def open_log(job: Job, command: Sequence[str], how: str):
    """``<job dir>/launch.log`` opened for appending, after a header line for this launch."""
    job.job_dir.mkdir(parents=True, exist_ok=True)
    log = open(job.log, "a")
    log.write(f"=== {time.strftime('%Y-%m-%d %H:%M:%S')} {how}: {shlex.join(command)}\n")
    log.flush()
    return log


def start_process(command: Sequence[str], log, env: dict[str, str],
                  ignore_signals: Sequence[int] = ()) -> subprocess.Popen:
    """Start a job in its own session (a Ctrl-C at the terminal reaches only the launcher, which
    forwards one SIGTERM) with ``ignore_signals`` ignored (SLURM's submitit signal)."""
    def ignore():
        for signum in ignore_signals:
            signal.signal(signum, signal.SIG_IGN)

    return subprocess.Popen(list(command), cwd=REPO, env=env, stdout=log,
                            stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            start_new_session=True, preexec_fn=ignore if ignore_signals else None)


def mark_done(job: Job) -> None:
    if job.done_marker is not None:
        checkpoint.atomic_write(job.done_marker, f"{time.strftime('%Y-%m-%d %H:%M:%S')}\n".encode())


def finished_after_exit(job: Job, code: int) -> tuple[str, str]:
    """(state, note) of a job whose process exited with ``code``."""
    if code == 0:
        mark_done(job)
    status = job_status(job)
    if status.state == "done":  # also a run stopped after its last checkpoint
        return "done", ""
    if code == 0:
        return "failed", f"exited 0 but is {status.state}; see {job.log}"
    if code in (128 + signal.SIGTERM, -signal.SIGTERM, 128 + signal.SIGINT, -signal.SIGINT):
        return "stopped", "resumable: relaunch to continue"
    return "failed", f"exit code {code}; see {job.log}"


# --- local backend -----------------------------------------------------------------------------


@dataclass
class _Progress:
    """Env-step rate of a running training job, from the launcher's observations."""

    started: float
    first_step: int | None = None
    first_time: float = 0.0
    rate: float | None = None

    def observe(self, step: int | None, now: float) -> None:
        if step is None:
            return
        if self.first_step is None:
            self.first_step, self.first_time = step, now
        elif step > self.first_step and now > self.first_time:
            self.rate = (step - self.first_step) / (now - self.first_time)


@dataclass
class LocalRunner:
    """Runs jobs as subprocesses, ``parallel`` at a time, and shows their status."""

    jobs: list[Job]
    parallel: int = 1
    interval: float | None = None  # seconds between tables (default: 5 on a TTY, 60 otherwise)
    out: object = sys.stdout
    poll_s: float = 0.5
    states: dict[int, str] = field(default_factory=dict)
    notes: dict[int, str] = field(default_factory=dict)
    _stop: int | None = None
    _kill: bool = False

    def _handle(self, signum, frame) -> None:
        if self._stop is not None:
            self._kill = True
        self._stop = signum

    def _print(self, text: str) -> None:
        self.out.write(text + "\n")
        self.out.flush()

    def run(self) -> int:
        tty = bool(getattr(self.out, "isatty", lambda: False)())
        interval = self.interval if self.interval is not None else (5.0 if tty else 60.0)
        statuses = {job.index: job_status(job) for job in self.jobs}
        queue = [job for job in self.jobs if statuses[job.index].launchable]
        for job in self.jobs:
            status = statuses[job.index]
            self.states[job.index] = "queued" if status.launchable else status.state
            if status.state == "done":
                self.notes[job.index] = "skipped: finished before this launch"
        running: dict[int, tuple[Job, subprocess.Popen, object, _Progress]] = {}
        env = job_env(self.parallel)
        previous = {sig: signal.signal(sig, self._handle) for sig in (signal.SIGINT,
                                                                      signal.SIGTERM)}
        shown_lines, last_table, forwarded, killed = 0, -math.inf, False, False
        try:
            while True:
                if self._stop is not None and not forwarded:
                    forwarded = True
                    name = signal.Signals(self._stop).name
                    self._print(f"{name}: stopping {len(running)} running job(s) (SIGTERM: they "
                                "save a checkpoint); a second signal kills them")
                    for _, process, _, _ in running.values():
                        _signal(process, signal.SIGTERM)
                if self._kill and not killed:
                    killed = True
                    for _, process, _, _ in running.values():
                        _signal(process, signal.SIGKILL)
                while self._stop is None and queue and len(running) < self.parallel:
                    job = queue.pop(0)
                    command = job.command()
                    log = open_log(job, command, "launch (local)")
                    running[job.index] = (job, start_process(command, log, env), log,
                                          _Progress(time.monotonic()))
                    self.states[job.index] = "running"
                    if not tty:
                        self._print(f"{_clock()} started {job.index} {job.name}: {job.log}")
                for index, (job, process, log, _) in list(running.items()):
                    code = process.poll()
                    if code is None:
                        continue
                    log.close()
                    del running[index]
                    state, note = finished_after_exit(job, code)
                    self.states[index], self.notes[index] = state, note
                    if not tty:
                        self._print(f"{_clock()} {state} {index} {job.name}"
                                    + (f": {note}" if note else ""))
                now = time.monotonic()
                finished = not running and (self._stop is not None or not queue)
                if finished or now - last_table >= interval:
                    last_table = now
                    table = self._table(running, now, tty)
                    if tty and shown_lines:
                        self.out.write(f"\x1b[{shown_lines}F\x1b[J")
                    self._print(table)
                    shown_lines = table.count("\n") + 1
                if finished:
                    break
                time.sleep(self.poll_s)
        finally:
            for _, process, log, _ in running.values():  # only after an error in the loop
                _signal(process, signal.SIGTERM)
                _reap(process, STOP_TIMEOUT_S)
                log.close()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        if self._stop is not None:
            return 128 + self._stop
        return 0 if all(state == "done" for state in self.states.values()) else 1

    def _table(self, running: dict, now: float, tty: bool) -> str:
        statuses, etas = {}, {}
        for job in self.jobs:
            status = job_status(job)
            if self.notes.get(job.index):
                status.note = self.notes[job.index]
            elif job.index in running:
                status.note = ""  # not "resumes from ...": it is resuming
            statuses[job.index] = status
            if job.index in running and job.kind == "train":
                progress = running[job.index][3]
                progress.observe(status.step, now)
                if progress.rate and status.total is not None:
                    etas[job.index] = max(0, status.total - status.step) / progress.rate
        limit = max(5, shutil.get_terminal_size().lines - 4) if tty else None
        return format_table(self.jobs, statuses, self.states, etas, limit)


def _signal(process: subprocess.Popen, signum: int) -> None:
    try:
        process.send_signal(signum)
    except ProcessLookupError:
        pass


def _clock() -> str:
    return time.strftime("%H:%M:%S")


# --- slurm backend -----------------------------------------------------------------------------


class SlurmJob(_Checkpointable):
    """The callable a SLURM array task runs: one job's command as a subprocess.

    On a timeout or preemption signal submitit calls :meth:`checkpoint`, which stops the
    command with SIGTERM (the trainer saves a checkpoint) and returns a requeue of this same
    callable; the requeued task reruns the command, which resumes from that checkpoint.
    """

    def __init__(self, command: Sequence[str], job_dir: str, done_marker: str | None = None,
                 env: dict[str, str] | None = None):
        self.command, self.job_dir, self.done_marker = list(command), str(job_dir), done_marker
        self.env = env or {}
        self._process: subprocess.Popen | None = None

    def __call__(self) -> int:
        log_dir = Path(self.job_dir)
        log_dir.mkdir(parents=True, exist_ok=True)
        env = job_env()
        env.update(self.env)
        with open(log_dir / LOG_FILE, "a") as log:
            log.write(f"=== {time.strftime('%Y-%m-%d %H:%M:%S')} launch (slurm "
                      f"{os.environ.get('SLURM_JOB_ID', 'local')}): {shlex.join(self.command)}\n")
            log.flush()
            usr = [getattr(signal, "SIG" + os.environ.get("SUBMITIT_PREEMPT_SIGNAL", "USR2"),
                           signal.SIGUSR2)]
            self._process = start_process(self.command, log, env, ignore_signals=usr)
            while (code := self._process.poll()) is None:  # not wait(): see checkpoint()
                time.sleep(1.0)
        self._process = None
        if code in (128 + signal.SIGTERM, -signal.SIGTERM):
            raise RuntimeError(f"the job was sent SIGTERM (preempted or cancelled) and saved a "
                               f"checkpoint; a requeue or relaunch resumes it ({log_dir})")
        if code != 0:
            raise RuntimeError(f"{shlex.join(self.command)} exited with {code}; see "
                               f"{log_dir / LOG_FILE} (relaunch to resume)")
        if self.done_marker:
            checkpoint.atomic_write(Path(self.done_marker),
                                    f"{time.strftime('%Y-%m-%d %H:%M:%S')}\n".encode())
        return code

    def checkpoint(self, *args, **kwargs):
        """Stop the command (it checkpoints) and requeue this job."""
        import submitit

        process = self._process
        if process is not None and process.returncode is None:
            _signal(process, signal.SIGTERM)
            if not _reap(process, STOP_TIMEOUT_S):
                _signal(process, signal.SIGKILL)
                _reap(process, 10)
        self._process = None
        return submitit.helpers.DelayedSubmission(self, *args, **kwargs)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_process"] = None  # a process does not travel with the pickled requeue
        return state


def _reap(process: subprocess.Popen, timeout: float) -> bool:
    """Wait for ``process`` to exit with ``os.waitpid``: Popen.wait/poll from a signal handler
    can spin on the lock the interrupted poll() holds. False if it still runs at ``timeout``."""
    deadline = time.monotonic() + timeout
    while process.returncode is None:
        try:
            pid, status = os.waitpid(process.pid, os.WNOHANG)
        except ChildProcessError:  # reaped by the interrupted poll()
            return True
        if pid:
            process.returncode = os.waitstatus_to_exitcode(status)
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.2)
    return True


def submit_slurm(jobs: Sequence[Job], experiment: Experiment, root: Path,
                 args: argparse.Namespace) -> list:
    """Submit ``jobs`` as one array through ``submitit.AutoExecutor``; returns submitit jobs."""
    try:
        import submitit
    except ImportError:
        raise LaunchError(INSTALL_SLURM) from None
    folder = Path(root) / experiment.name / SUBMITIT_DIR
    common = dict(name=f"vsgjax-{experiment.name}", timeout_min=args.time,
                  gpus_per_node=args.gpus_per_job, cpus_per_task=args.cpus_per_job,
                  mem_gb=args.mem)
    if args.cluster == "local":  # submitit's local executor: this machine, same requeue path
        executor = submitit.LocalExecutor(folder=folder, max_num_timeout=args.max_requeues)
        parameters = dict(common, signal_delay_s=args.signal_delay)
    else:
        try:
            executor = submitit.AutoExecutor(folder=folder, cluster="slurm",
                                             slurm_max_num_timeout=args.max_requeues)
        except RuntimeError as error:  # no srun / sbatch on this machine
            raise LaunchError(f"{error}; submit from the cluster's login node, or write an "
                              "sbatch script with --backend print") from None
        parameters = dict(common, slurm_partition=args.partition,
                          slurm_array_parallelism=args.jobs,
                          slurm_signal_delay_s=args.signal_delay)
    executor.update_parameters(**{k: v for k, v in parameters.items() if v is not None})
    return executor.submit_array([
        SlurmJob(job.command(), str(job.job_dir),
                 str(job.done_marker) if job.done_marker else None) for job in jobs])


def wait_slurm(jobs: Sequence[Job], submitted: Sequence, out, interval: float) -> int:
    """Show the table until every submitted job ended; 0 when all of them succeeded."""
    states = {job.index: "submitted" for job in jobs}
    by_index = dict(zip([job.index for job in jobs], submitted, strict=True))
    failed = False
    while True:
        for index, handle in by_index.items():
            if states[index] in ("done", "failed"):
                continue
            if handle.done():
                try:
                    handle.result()
                    states[index] = "done"
                except Exception as error:  # the job's failure, reported in the table
                    states[index], failed = "failed", True
                    out.write(f"job {index} failed: {str(error).splitlines()[-1][:300]}\n")
            else:
                states[index] = handle.state.lower()
        ended = all(state in ("done", "failed") for state in states.values())
        statuses = {job.index: job_status(job) for job in jobs}
        for index, state in states.items():
            if state not in ("done", "failed"):
                statuses[index].note = ""
        out.write(format_table(jobs, statuses, states) + "\n")
        out.flush()
        if ended:
            return 1 if failed else 0
        time.sleep(interval)


# --- print backend -----------------------------------------------------------------------------


def write_print(jobs: Sequence[Job], experiment: Experiment, root: Path,
                args: argparse.Namespace) -> tuple[Path, Path]:
    """``commands.txt`` (one shell command per job) and ``sbatch.sh`` (an array over its lines)."""
    directory = Path(root) / experiment.name
    directory.mkdir(parents=True, exist_ok=True)
    lines = []
    for job in jobs:
        line = shlex.join(job.command())
        if job.done_marker is not None:
            line += f" && touch {shlex.quote(str(job.done_marker))}"
        lines.append(line)
    commands = directory / COMMANDS_FILE
    checkpoint.atomic_write(commands, "".join(f"{line}\n" for line in lines).encode())
    (directory / ".sbatch").mkdir(exist_ok=True)
    options = [f"--job-name=vsgjax-{experiment.name}",
               f"--array=0-{len(jobs) - 1}" + (f"%{args.jobs}" if args.jobs else ""),
               f"--output={directory / '.sbatch'}/%A_%a.out", "--open-mode=append",
               f"--time={args.time}", f"--cpus-per-task={args.cpus_per_job}",
               "--signal=B:USR1@120", "--requeue"]
    if args.gpus_per_job:
        options.append(f"--gpus-per-node={args.gpus_per_job}")
    if args.mem:
        options.append(f"--mem={int(args.mem)}G")
    if args.partition:
        options.append(f"--partition={args.partition}")
    dirs = " ".join(shlex.quote(str(job.job_dir)) for job in jobs)
    script = "\n".join([
        "#!/bin/bash",
        f"# {experiment.name}: {len(jobs)} jobs, one per line of {commands}.",
        f"# Submit with: sbatch {directory / SBATCH_FILE}",
        "# Array task i runs line i+1, appending its output to <job dir>/launch.log. Two minutes",
        "# before the time limit it stops the command (SIGTERM: the trainer saves a checkpoint)",
        "# and requeues itself; the requeued task resumes from that checkpoint.",
        *(f"#SBATCH {option}" for option in options),
        "",
        f"cd {shlex.quote(str(REPO))}",
        f"DIRS=({dirs})",
        'DIR="${DIRS[$SLURM_ARRAY_TASK_ID]}"',
        f'LINE=$(sed -n "$((SLURM_ARRAY_TASK_ID + 1))p" {shlex.quote(str(commands))})',
        'mkdir -p "$DIR"',
        'echo "=== $(date "+%F %T") launch (sbatch ${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}):'
        ' $LINE" | tee -a "$DIR/launch.log"',
        'setsid bash -c "$LINE" >> "$DIR/launch.log" 2>&1 &',
        "CHILD=$!",
        'trap \'echo "time limit near: stopping and requeueing"; kill -TERM -- -$CHILD; '
        'wait $CHILD; scontrol requeue "${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}"; '
        "exit 0' USR1",
        "wait $CHILD",
        "exit $?",
        "",
    ])
    sbatch = directory / SBATCH_FILE
    checkpoint.atomic_write(sbatch, script.encode())
    sbatch.chmod(0o755)
    return commands, sbatch


# --- command line ------------------------------------------------------------------------------


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.launch", description=__doc__.split("\n")[0],
        epilog="See docs/experiments.md.")
    add_selection_arguments(parser)
    parser.add_argument("--backend", default="local", choices=BACKENDS)
    parser.add_argument("--jobs", type=int, default=None,
                        help="jobs at a time (local: default 1; slurm / print: the array's "
                             "parallelism, default unlimited)")
    parser.add_argument("--status", action="store_true", help="print the table, launch nothing")
    parser.add_argument("--task", action="append", default=[],
                        help="only this task's runs (repeat or comma-separate)")
    parser.add_argument("--model", action="append", default=[],
                        help="only this model's runs (vsg, or vsg-<variant>; repeatable)")
    parser.add_argument("--interval", type=float, default=None,
                        help="seconds between status tables (default 5 on a TTY, else 60)")
    slurm = parser.add_argument_group("slurm and print backends")
    slurm.add_argument("--partition", default=None)
    slurm.add_argument("--gpus-per-job", type=int, default=1)
    slurm.add_argument("--cpus-per-job", type=int, default=8)
    slurm.add_argument("--time", type=int, default=1440,
                       help="minutes per SLURM job before it is requeued (default 1440)")
    slurm.add_argument("--mem", type=float, default=None, help="GB per job")
    slurm.add_argument("--max-requeues", type=int, default=50,
                       help="timeouts after which a job is not requeued again (default 50)")
    slurm.add_argument("--signal-delay", type=int, default=None,
                       help="seconds before the time limit at which a job checkpoints and "
                            "requeues (submitit's default: 90)")
    slurm.add_argument("--cluster", default="slurm", choices=("slurm", "local"),
                       help="submitit's executor: slurm, or local to try the backend on this "
                            "machine")
    slurm.add_argument("--wait", action="store_true",
                       help="slurm: stay and show the table until the jobs end")
    args = parser.parse_args(argv)
    args.task = [t for value in args.task for t in value.split(",") if t]
    args.model = [m for value in args.model for m in value.split(",") if m]
    if args.jobs is not None and args.jobs < 1:
        parser.error(f"--jobs must be a positive integer, got {args.jobs}")
    return args


def main(argv: list[str] | None = None, out=None) -> int:
    out = out or sys.stdout
    args = parse_args(argv)
    root = args.root.absolute()
    try:
        names = experiment_names(args.definitions)
        if args.name not in names:
            raise LaunchError(f"unknown experiment {args.name!r}; valid: "
                              f"{', '.join(names) or f'none in {args.definitions}'}")
        experiment = load_experiment(args.name, args.size, args.seeds, args.steps,
                                     args.definitions)
        jobs = make_jobs(experiment, root, args.task, args.model)
        if args.backend == "slurm" and not args.status and _Checkpointable is object:
            raise LaunchError(INSTALL_SLURM)
    except (ExperimentError, LaunchError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    statuses = {job.index: job_status(job) for job in jobs}
    if args.status or not jobs:
        out.write(format_table(jobs, statuses, {}) + "\n")
        return 0
    if args.backend == "local":
        return LocalRunner(jobs, args.jobs or 1, args.interval, out).run()
    todo = [job for job in jobs if statuses[job.index].launchable]
    out.write(format_table(jobs, statuses, {}) + "\n")
    if not todo:
        out.write("nothing to launch\n")
        return _exit_code(statuses)
    if args.backend == "print":
        commands, sbatch = write_print(todo, experiment, root, args)
        out.write(f"{len(todo)} commands: {commands}\nsbatch array script: {sbatch}\n")
        return 0
    try:
        submitted = submit_slurm(todo, experiment, root, args)
    except LaunchError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    ids = ", ".join(str(handle.job_id) for handle in submitted)
    out.write(f"submitted {len(submitted)} jobs ({ids}); submitit files in "
              f"{root / experiment.name / SUBMITIT_DIR}\n")
    if not args.wait:
        out.write(f"follow with: python -m experiments.launch {args.name} --status "
                  f"{_rebuild_flags(args)}\n")
        return 0
    try:
        return wait_slurm(todo, submitted, out, args.interval or 10.0)
    except KeyboardInterrupt:
        out.write("stopped waiting; the submitted jobs keep running (see --status)\n")
        return 130


def _exit_code(statuses: dict[int, Status]) -> int:
    return 0 if all(s.state == "done" for s in statuses.values()) else 1


def _rebuild_flags(args: argparse.Namespace) -> str:
    flags = [f"--size {args.size}", f"--root {shlex.quote(str(args.root))}"]
    flags += [f"--seeds {args.seeds}"] if args.seeds else []
    flags += [f"--steps {args.steps}"] if args.steps else []
    flags += [f"--definitions {shlex.quote(str(args.definitions))}"] if \
        args.definitions != PAPER_DIR else []
    return " ".join(flags)


if __name__ == "__main__":
    sys.exit(main())
