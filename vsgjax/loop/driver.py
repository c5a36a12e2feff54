"""The driver both training loops share: the schedule, logs, evaluation, checkpoints, resume,
stopping seeds on non-finite metrics, SIGINT/SIGTERM and the end of training.

A loop (:class:`~vsgjax.loop.host_trainer.HostTrainer`,
:class:`~vsgjax.loop.device_trainer.DeviceTrainer`) subclasses :class:`LoopDriver` and adds
only how it collects and updates (:meth:`LoopDriver.step`), how it runs evaluation episodes,
what its checkpoint holds, and how it reports a log line.
"""

from __future__ import annotations

import dataclasses
import math
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from vsgjax.config import Config, ConfigError, to_dict
from vsgjax.data import checkpoint
from vsgjax.loop.evaluator import summarize
from vsgjax.loop.logger import Progress
from vsgjax.loop.rundir import RunDir, RunWriter
from vsgjax.loop.schedule import Counters, Schedule
from vsgjax.loop.stop_signal import StopSignal


class SeedEval(NamedTuple):
    """One seed's evaluation: its episodes' infos, its first episode as recorded (for the
    videos; None where the loop records none), and its agent's open-loop errors on its
    evaluation episodes (``{"obs_mse": [H], "reward_mse": [H]}``; None for an agent without the
    ``open_loop_errors`` hook)."""

    infos: list[dict]
    recorded: dict | None = None
    open_loop: dict | None = None


class NonFiniteLossError(RuntimeError):
    """An update produced a NaN or infinite metric; its state was not kept."""


def non_finite(metrics: dict, update: int, env_steps: int) -> str | None:
    """What is non-finite in an update's metrics (None when everything is finite)."""
    bad = {k: float(v) for k, v in metrics.items() if not math.isfinite(float(v))}
    if not bad:
        return None
    listed = ", ".join(f"{k}={v}" for k, v in sorted(bad.items()))
    return f"non-finite metrics at update {update} (env step {env_steps}): {listed}"


def group_label(seeds: list[int]) -> str:
    return ",".join(map(str, seeds))


def check_seed_group(configs: list[Config], logdirs: list[Path]) -> None:
    """The seeds of one run: distinct seeds and log directories, configs equal but the seed."""
    seeds = [c.train.seed for c in configs]
    if len(configs) != len(logdirs) or not configs:
        raise ConfigError(f"{len(configs)} configs for {len(logdirs)} log directories")
    if len(set(seeds)) != len(seeds) or len(set(logdirs)) != len(logdirs):
        raise ConfigError(f"seeds {seeds} and log directories must be distinct")
    shared = [to_dict(dataclasses.replace(c, train=dataclasses.replace(c.train, seed=0)))
              for c in configs]
    if any(other != shared[0] for other in shared):
        raise ConfigError("the seeds of one run must share every config value but train.seed")


def open_runs(make_run: Callable[[Config, Path], RunWriter], configs: list[Config],
              logdirs: list[Path]) -> list[RunWriter]:
    """Each seed's run directory, opened (locked and checked) in turn, then, once every seed's
    is, prepared (``make_run`` gives them unprepared): a refusal of any seed's directory comes
    before anything in any of them is moved. When one cannot be opened, the ones before are
    unlocked again."""
    runs = []
    try:
        for config, logdir in zip(configs, logdirs, strict=True):
            runs.append(make_run(config, logdir))
        for run in runs:
            run.prepare()
    except BaseException:
        unlock_runs(runs)
        raise
    return runs


def unlock_runs(runs: list[RunWriter]) -> None:
    """Unlock the run directories of a trainer that failed to start."""
    for run in runs:
        run.unlock()


Restore = Callable[[RunWriter, "int | None"], "checkpoint.Checkpoint | None"]


def restore_seeds(runs: list[RunWriter], restore: Restore) -> list[checkpoint.Checkpoint] | None:
    """Every seed's checkpoint of one step (the newest they all have), or None for a new run.

    ``restore(run, max_step)``: the run's newest readable checkpoint up to ``max_step``. The
    seeds save one after the other; a run killed between two saves resumes all of them from
    the step before (``checkpoint.save`` then drops the newer one on the next save).
    """
    restored = [restore_own(run, restore, None) for run in runs]
    if all(c is None for c in restored):
        return None
    missing = [run.seed for run, c in zip(runs, restored, strict=True) if c is None]
    if missing:
        raise ConfigError(
            f"seeds {group_label(missing)} have no checkpoint while the other seeds have one; "
            "the seeds of one process train in lockstep: train them in separate runs")
    step = min(c.step for c in restored)
    restored = [c if c.step == step else restore_own(run, restore, step)
                for run, c in zip(runs, restored, strict=True)]
    counters = [saved_counters(c) if c else None for c in restored]
    if any(c is None or c.step != step for c in restored) or any(
            other != counters[0] for other in counters):
        raise ConfigError(f"seeds {group_label([r.seed for r in runs])} have no common "
                          f"checkpoint to resume from (newest common step {step}); resume them "
                          "in separate runs")
    return restored


def restore_own(run: RunWriter, restore: Restore,
                max_step: int | None) -> checkpoint.Checkpoint | None:
    """``restore(run, max_step)``, falling back past checkpoints that do not fit the run's
    model: another run's, written before checkpoints held their config, so that only their
    arrays tell. Once an older one fits, those are moved to ``checkpoints/foreign/`` (and
    said, :attr:`RunWriter.foreign_moved`); when none fits, the newest one's error, nothing
    moved."""
    misfits: dict[Path, checkpoint.CheckpointMismatchError] = {}
    while True:
        try:
            restored = restore(run, max_step)
        except checkpoint.CheckpointMismatchError as error:
            misfits[error.path] = error
            older = [step for step, _ in run.checkpoints() if step < error.step]
            max_step = older[-1] if older else None
            if older:
                continue
            restored = None
        if misfits and restored is None:
            raise next(iter(misfits.values()))
        run.set_aside_foreign({path: f"it does not fit this run's model: {error.reason}"
                               for path, error in misfits.items()})
        return restored


class FirstUpdate(NamedTuple):
    """When a new run makes its first update: at env step ``step``, in the collection that
    starts below ``smallest_steps`` (the least ``train.steps`` that trains); ``why`` in words."""

    step: int
    smallest_steps: int
    why: str


def check_first_update(config: Config, logdirs: list[Path], first: FirstUpdate, *,
                       restart: bool = False) -> None:
    """ConfigError when a new run (no checkpoint in any of ``logdirs``, or ``restart``) would
    end before its first update: it would collect and evaluate, and train nothing."""
    steps = config.train.steps
    if steps >= first.smallest_steps or (
            not restart and any(RunDir(d).checkpoints() for d in logdirs)):
        return
    again = "starting over with --restart, " if restart else ""
    raise ConfigError(f"train.steps={steps} ends before the run's first update, at env step "
                      f"{first.step} ({first.why}), so {again}it would train nothing; the "
                      f"smallest train.steps that trains is {first.smallest_steps}")


def saved_counters(restored: checkpoint.Checkpoint) -> Counters:
    return Counters(**{k: v for k, v in restored.meta["counters"].items() if k != "episodes"})


class LoopDriver:
    """:meth:`run`: :meth:`iteration` to ``train.steps``, the final evaluation, the checkpoint
    on SIGINT/SIGTERM and at the end.

    A subclass sets ``config``, ``out``, ``runs`` (one :class:`RunWriter` per seed) and calls
    :meth:`start` once its state is restored; it implements :meth:`step`,
    :meth:`eval_episodes`, :meth:`checkpoint_of`, :meth:`report_log` and :meth:`describe`.
    """

    config: Config
    runs: list[RunWriter]

    def start(self, counters: Counters, *, progress: bool) -> None:
        """Open every seed's logs at the restored step and start the clocks."""
        self.schedule = Schedule(self.config, counters)
        self.stopped: list[int] = []  # seeds stopped on non-finite metrics
        for run in self.runs:
            run.open_logs(self.env_steps)
        self.progress = Progress(self.config.train.steps, self.env_steps, enabled=progress)
        self._shown: dict[str, dict[int, float]] = {}  # progress-bar values per seed
        self._last_log_time, self._last_log_step = time.monotonic(), self.env_steps
        self._clock = (time.monotonic(), 0.0)  # CPU seconds count from the process's start

    @property
    def counters(self) -> Counters:
        return self.schedule.counters

    @property
    def env_steps(self) -> int:
        return self.schedule.env_steps

    @property
    def seeds(self) -> list[int]:
        return [run.seed for run in self.runs]

    def tick(self) -> None:
        """Charge the wall and CPU seconds since the last tick to every running seed."""
        now = (time.monotonic(), time.process_time())
        self.counters.wall_s += (now[0] - self._clock[0]) / len(self.runs)
        self.counters.cpu_s += (now[1] - self._clock[1]) / len(self.runs)
        self._clock = now

    # --- what a loop adds ----------------------------------------------------------------------

    def step(self) -> None:
        """Collect and make the updates due (advancing ``counters.agent_steps``/``updates``)."""
        raise NotImplementedError

    def eval_episodes(self) -> list[SeedEval]:
        """Each seed's evaluation (:class:`SeedEval`)."""
        raise NotImplementedError

    def checkpoint_of(self, index: int) -> tuple[dict, dict]:
        """The checkpoint tree of seed ``index`` and the metadata besides the counters."""
        raise NotImplementedError

    def report_log(self, records: list[dict], shared: dict) -> None:
        """Show a log interval's records (progress bar or a line)."""

    def videos(self, step: int, recorded: list[dict]) -> None:
        """Write the eval and open-loop videos of ``recorded`` (one episode per seed)."""

    def parallel_line(self) -> str | None:
        """How the seeds and devices are laid out, when there is more than one of either."""
        return None

    def close_loop(self) -> None:
        """Close what the loop opened besides the run directories (envs)."""

    # --- the loop --------------------------------------------------------------------------

    def run(self) -> int:
        """Train to ``train.steps`` env steps; returns the process exit code."""
        train = self.config.train
        if self.env_steps >= train.steps and not self.schedule.final_eval_due():
            self.progress.close()
            self.out(f"nothing to train: the run is already at env step {self.env_steps}, "
                     f"evaluated and saved (train.steps={train.steps}); a higher train.steps "
                     "trains it further")
            return 0
        with StopSignal() as stop:
            while self.env_steps < train.steps and not stop.requested:
                self.iteration()
                self.tick()
            if not stop.requested and self.schedule.final_eval_due():
                self.evaluate()  # the final score
            self.save()
        self.progress.close()
        if stop.requested:
            name = signal.Signals(stop.received).name
            self.out(f"{name}: saved a checkpoint at env step {self.env_steps}; rerun the "
                     "same command to resume")
            return 128 + stop.received
        self.out(f"done: {self.env_steps} env steps, {self.counters.updates} updates")
        return self.exit_code()

    def iteration(self) -> None:
        """One pass of the loop: collection and updates, then the logs, evaluation and
        checkpoint now due."""
        self.step()
        if self.schedule.log_due():
            self.log()
        if self.schedule.eval_due():
            self.evaluate()
            self.schedule.eval_done()
        if self.schedule.ckpt_due():
            self.save()

    def log(self) -> None:
        """Every seed's train record of this log interval, then :meth:`report_log`."""
        self.schedule.log_done()
        now = time.monotonic()
        shared = {"env_steps_per_s": (self.env_steps - self._last_log_step)
                  / max(now - self._last_log_time, 1e-9), "updates": self.counters.updates}
        records = [run.log(self.env_steps, shared) for run in self.runs]
        self.report_log(records, shared)
        self._last_log_time, self._last_log_step = now, self.env_steps

    def evaluate(self) -> None:
        """``train.eval_episodes`` episodes of each seed's actor mode -> scores, eval records,
        the open-loop errors (agents with a world model), the message, and videos when due."""
        step = self.env_steps
        self.progress.write(f"evaluating at env step {step}: {self.config.train.eval_episodes} "
                            "episodes of the actor's mode per seed")
        results = self.eval_episodes()
        self.tick()
        clocks = {"wall_s": self.counters.wall_s, "cpu_s": self.counters.cpu_s}
        for run, result in zip(self.runs, results, strict=True):
            infos = result.infos
            summary = {**summarize(infos), **clocks}
            run.record_eval(step, infos, summary, result.open_loop)
            self.progress.write(f"{self._prefix(run)}eval  env step {step:>9}: return "
                                f"{summary['return']:.3f} ± {summary['return_std']:.3f} over "
                                f"{len(infos)} episodes")
            self._show("eval", {run.seed: summary["return"]})
        self.counters.last_eval = step
        recorded = [result.recorded for result in results]
        if recorded[0] is not None and self.schedule.video_due():
            self.schedule.video_done()
            self.videos(step, recorded)

    def save(self) -> None:
        self.schedule.ckpt_done()
        self.tick()
        for i, run in enumerate(self.runs):
            tree, meta = self.checkpoint_of(i)
            run.save(self.env_steps, self.counters, tree, **meta)

    def close(self) -> None:
        self.progress.close()
        self.close_loop()
        for run in self.runs:
            run.close()

    # --- messages and stopping seeds -------------------------------------------------------

    def exit_code(self) -> int:
        """1 when seeds stopped early on non-finite metrics (the others finished), else 0."""
        if self.stopped:
            self.out(f"seeds {group_label(self.stopped)} stopped early on non-finite metrics")
            return 1
        return 0

    def _prefix(self, run: RunWriter) -> str:
        """``seed k: `` before a message about one seed, when a run has several."""
        return f"seed {run.seed}: " if len(self.runs) > 1 or self.stopped else ""

    def _show(self, name: str, values: dict[int, float]) -> None:
        """Show ``name`` on the progress bar for the seeds given (one value per seed, / apart)."""
        shown = self._shown.setdefault(name, {})
        shown.update(values)
        self.progress.show({name: [shown.get(seed, math.nan) for seed in self.seeds]})

    def _stop_runs(self, problems: list[str | None]) -> list[int]:
        """Report and close the runs whose problem (a non-finite update) is not None and keep
        the others in ``self.runs``; returns their indices. Raises NonFiniteLossError when
        none is left."""
        keep = [i for i, problem in enumerate(problems) if problem is None]
        others = "; the other seeds go on" if keep else ""
        for run, problem in zip(self.runs, problems, strict=True):
            if problem is not None:
                self.stopped.append(run.seed)
                print(f"error: {self._prefix(run)}training stopped: {problem}; the non-finite "
                      f"state was not saved; {run.last_good_checkpoint()}{others}",
                      file=sys.stderr, flush=True)
                run.close()
        if not keep:
            raise NonFiniteLossError(f"seeds {group_label(self.stopped)} stopped")
        self.runs = [self.runs[i] for i in keep]
        return keep
