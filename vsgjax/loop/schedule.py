"""What is due at an env step: updates, logs, evaluations, videos, checkpoints (both loops).

Thresholds are in env steps (agent steps x ``env.action_repeat``) except the checkpoint's,
which counts updates. The evaluation grid starts when training starts (the release evaluates
then) and repeats every ``train.eval_every`` env steps.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vsgjax.config import Config


@dataclasses.dataclass
class Counters:
    """The schedule's state, shared by the seeds of a run (they train in lockstep); saved in
    every checkpoint, with the seed's own episode count beside it."""

    agent_steps: int = 0
    updates: int = 0
    train_start: int = -1  # agent step at which training began (-1 while prefilling)
    next_log: int = 0
    next_eval: int = 0  # the end of prefill, then every train.eval_every env steps after it
    next_video: int = 0
    last_eval: int = -1  # env step of the latest evaluation
    last_ckpt_updates: int = 0
    last_ckpt_step: int = -1  # env step of the latest checkpoint
    # the run's wall and CPU seconds (all threads) so far; a process training S seeds charges
    # each 1/S of its time
    wall_s: float = 0.0
    cpu_s: float = 0.0


def next_multiple(value: int, every: int) -> int:
    """The smallest multiple of ``every`` strictly above ``value``."""
    return (value // every + 1) * every


def next_on_grid(origin: int, value: int, every: int) -> int:
    """The smallest ``origin + k·every`` (k >= 1) strictly above ``value``."""
    return origin + max(1, next_multiple(value - origin, every) // every) * every


def env_seed(seed: int, agent_steps: int) -> int:
    """Training env seed: ``seed`` for a new run, a distinct derived seed after each resume."""
    if agent_steps == 0:
        return seed
    return int(np.random.SeedSequence([seed, agent_steps]).generate_state(1)[0] % 2**31)


class Schedule:
    """The counters of a run read against its config: ``*_due`` asks, ``*_done`` advances."""

    def __init__(self, config: Config, counters: Counters | None = None):
        self.train, self.action_repeat = config.train, config.env.action_repeat
        self.counters = Counters() if counters is None else counters

    @property
    def env_steps(self) -> int:
        return self.counters.agent_steps * self.action_repeat

    @property
    def training(self) -> bool:
        return self.counters.train_start >= 0

    def start_training(self) -> None:
        """Prefill ended: the update count and the evaluation grid start here."""
        c = self.counters
        c.train_start, c.next_eval = c.agent_steps, self.env_steps

    def updates_due(self) -> int:
        """The updates owed by now at the train ratio: pretraining, then one per
        ``train.train_every`` agent steps since training started."""
        c = self.counters
        return self.train.pretrain + 1 + (c.agent_steps - c.train_start) // self.train.train_every

    def log_due(self) -> bool:
        return self.env_steps >= self.counters.next_log

    def log_done(self) -> None:
        self.counters.next_log = next_multiple(self.env_steps, self.train.log_every)

    def eval_due(self) -> bool:
        return self.training and self.env_steps >= self.counters.next_eval

    def eval_done(self) -> None:
        c = self.counters
        c.last_eval = self.env_steps
        c.next_eval = next_on_grid(c.next_eval, self.env_steps, self.train.eval_every)

    def final_eval_due(self) -> bool:
        """Whether the end of training still needs its evaluation (the final score)."""
        return self.counters.last_eval != self.env_steps

    def video_due(self) -> bool:
        return self.env_steps >= self.counters.next_video

    def video_done(self) -> None:
        self.counters.next_video = next_multiple(self.env_steps, self.train.video_every)

    def ckpt_due(self) -> bool:
        """Every ``train.ckpt_every`` updates, and right after the first evaluation: a run
        killed between that evaluation and its first checkpoint would hold scores that no
        checkpoint resumes, which training refuses to overwrite."""
        c = self.counters
        first_evaluation_unsaved = c.last_eval >= 0 and c.last_ckpt_step < 0
        return first_evaluation_unsaved or c.updates >= c.last_ckpt_updates + self.train.ckpt_every

    def ckpt_done(self) -> None:
        self.counters.last_ckpt_updates = self.counters.updates
        self.counters.last_ckpt_step = self.env_steps
