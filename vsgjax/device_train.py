"""The host side of ``train.loop=device``: logs, evaluation and checkpoints between calls.

Each call of the compiled loop (:mod:`vsgjax.device_loop`) is one episode of every env of every
seed; between calls this driver writes the same log directory as the host loop (config,
metrics, scores, eval episodes, every episode as an MCAP file, checkpoints; no videos: the MJX
tasks have no pixels), evaluates on the release's grid and checkpoints. The checkpoint holds the
whole loop state (agent, device replay, PRNG key); the envs need none, since every call starts
by resetting them. Resuming, SIGINT/SIGTERM and the NaN stop behave as in the host loop: a seed
whose update in a call is non-finite stops (that call's state of it is dropped, its last
checkpoint stays) and the other seeds go on, recompiled for the seeds left.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax import checkpoint
from vsgjax.config import Config
from vsgjax.device_loop import DeviceLoop, LoopState
from vsgjax.logger import Progress
from vsgjax.parallel import seed_batched, stack, take
from vsgjax.train import (
    Counters,
    LoopDriver,
    RunFiles,
    check_seed_group,
    group_label,
    next_on_grid,
    non_finite,
)


class DeviceRun(RunFiles):
    """One seed's log directory in the device loop (its replay lives on the device)."""

    replay_steps = 0  # set by the trainer after every call


class DeviceTrainer(LoopDriver):
    """Train one or more seeds of an ``mjx_`` task with the fully jitted loop."""

    def __init__(self, configs: list[Config], logdirs: list[Path], *, progress: bool = True,
                 out=print):
        from vsgjax.envs.mjx import make_mjx_task

        check_seed_group(configs, logdirs)
        self.config, self.out = configs[0], out
        env = self.config.env
        task = make_mjx_task(env.task, env.action_repeat, env.time_limit)
        self.loop = DeviceLoop(self.config, task)
        self.loop.check()
        self.runs = [DeviceRun(c, d) for c, d in zip(configs, logdirs, strict=True)]
        self.stopped: list[int] = []
        self._compile(len(self.runs))
        self.state, self.counters, self.resumed = self._restore()
        for run in self.runs:
            run.open_logs(self.env_steps)
        self._update_replay_steps()
        self.progress = Progress(self.config.train.steps, self.env_steps, enabled=progress)
        self._started, self._start_steps = time.monotonic(), self.env_steps

    def _compile(self, seeds: int) -> None:
        """The jitted programs of ``seeds`` stacked seeds (again after seeds stop)."""
        train = self.config.train
        self._episode = {training: jax.jit(seed_batched(
            lambda state, training=training: self.loop.episode(state, training), seeds))
            for training in (False, True)}
        self._pretrain = jax.jit(seed_batched(
            lambda state: self.loop.pretrain(state, train.pretrain), seeds))
        self._evaluate = jax.jit(seed_batched(
            lambda params, key: self.loop.evaluate(params, key, train.eval_episodes), seeds))

    def _target(self, run: RunFiles) -> LoopState:
        return jax.eval_shape(self.loop.init, jax.random.PRNGKey(run.seed))

    def _restore(self) -> tuple[LoopState, Counters, bool]:
        restored = [checkpoint.restore(run.ckpt_dir, {"loop": self._target(run)})
                    for run in self.runs]
        if all(c is None for c in restored):
            states = [self.loop.init(jax.random.PRNGKey(run.seed)) for run in self.runs]
            return stack(states), Counters(), False
        steps = {None if c is None else c.step for c in restored}
        if len(steps) != 1:
            raise ValueError(f"seeds {group_label([r.seed for r in self.runs])} have "
                             f"checkpoints of different steps {sorted(map(str, steps))}; "
                             "resume them in separate runs")
        for run, ckpt in zip(self.runs, restored, strict=True):
            run.load(ckpt)
        counters = {k: v for k, v in restored[0].meta["counters"].items() if k != "episodes"}
        return stack([c.tree["loop"] for c in restored]), Counters(**counters), True

    @property
    def env_steps(self) -> int:
        return self.counters.agent_steps * self.config.env.action_repeat

    def describe(self) -> str:
        loop = self.loop
        what = (f"device loop: {self.config.env.num_envs} envs x {loop.episode_steps} agent "
                f"steps per call, {loop.updates_per_episode} updates per call once trained, "
                f"replay of {loop.replay_episodes} episode batches")
        if not self.resumed:
            return f"starting a new run; {what}"
        return (f"resuming from {self.runs[0].checkpoint_path.name}: env step {self.env_steps}, "
                f"update {self.counters.updates}; {what}")

    def _update_replay_steps(self) -> None:
        stored = np.asarray(self.state.replay.stored)
        per_batch = self.config.env.num_envs * (self.loop.episode_steps + 1)
        for run, count in zip(self.runs, stored, strict=True):
            run.replay_steps = int(min(count, self.loop.replay_episodes)) * per_batch

    # --- the loop ----------------------------------------------------------------------------

    @property
    def prefilling(self) -> bool:
        return self.env_steps < self.config.train.prefill

    def iteration(self) -> None:
        """One call of the compiled loop (one episode of every env), then logs, eval, saves."""
        c, train = self.counters, self.config.train
        training = not self.prefilling
        if training and c.train_start < 0:
            self._start_training()
        started = time.monotonic()
        self.state, metrics, records = self._episode[training](self.state)
        records = jax.device_get(records)
        c.agent_steps += self.config.env.num_envs * self.loop.episode_steps
        if training:
            keep = self._take_metrics(jax.device_get(metrics), self.loop.updates_per_episode)
            records = {k: v[keep] for k, v in records.items()}
        self._update_replay_steps()
        self._write_episodes(records)
        self.progress.update(self.env_steps)
        self.progress.show({"call_s": time.monotonic() - started, "upd": c.updates})
        self._log()
        if c.train_start >= 0 and self.env_steps >= c.next_eval:
            self.evaluate()
            c.next_eval = next_on_grid(c.next_eval, self.env_steps, train.eval_every)
        if c.updates >= c.last_ckpt_updates + train.ckpt_every:
            self.save()

    def _start_training(self) -> None:
        c, train = self.counters, self.config.train
        c.train_start, c.next_eval = c.agent_steps, self.env_steps
        self.progress.write(f"prefill done at env step {self.env_steps}; compiling the "
                            f"training call, {train.pretrain} pretraining updates")
        if train.pretrain:
            self.state, metrics = self._pretrain(self.state)
            self._take_metrics(jax.device_get(metrics), train.pretrain)

    def _take_metrics(self, metrics: dict, updates: int) -> list[int]:
        """Check ``updates`` updates' metrics ``[S, U]`` of every seed and keep their means; a
        seed with a non-finite one stops (its state of this call is dropped; the others go on).
        Returns the indices of the seeds kept."""
        problems = []
        for i, run in enumerate(self.runs):
            seed_metrics = {k: np.asarray(v[i]) for k, v in metrics.items()}
            problem = next(filter(None, (
                non_finite({k: v[u] for k, v in seed_metrics.items()},
                           self.counters.updates + u + 1, self.env_steps)
                for u in range(updates))), None)
            problems.append(problem)
            if problem is None:
                run.window.append({k: float(v.mean()) for k, v in seed_metrics.items()})
        self.counters.updates += updates
        if not any(problems):
            return list(range(len(problems)))
        keep = self._stop_runs(problems)
        self.state = take(self.state, keep)
        self._compile(len(keep))
        return keep

    def _write_episodes(self, records: dict) -> None:
        """Every env's finished episode -> its seed's episodes/ and episode metrics."""
        for i, run in enumerate(self.runs):
            for env in range(self.config.env.num_envs):
                episode = {k: np.asarray(v[i, env]) for k, v in records.items()}
                info = {"return": float(episode["reward"].sum()),
                        "length": len(episode["reward"]) - 1}
                run.on_episode(episode, info, self.env_steps)

    def _log(self) -> None:
        c = self.counters
        if self.env_steps < c.next_log:
            return
        c.next_log = (self.env_steps // self.config.train.log_every + 1) * \
            self.config.train.log_every
        elapsed = max(time.monotonic() - self._started, 1e-9)
        shared = {"env_steps_per_s": (self.env_steps - self._start_steps) / elapsed,
                  "updates": c.updates}
        records = [run.log(self.env_steps, shared) for run in self.runs]
        returns = "/".join(f"{r['return']:.3g}" for r in records if "return" in r)
        self.progress.write(f"train env step {self.env_steps:>9}: updates {c.updates}, "
                            f"return {returns}")

    def evaluate(self) -> None:
        train, step = self.config.train, self.env_steps
        keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(run.seed), step)
                          for run in self.runs])
        results = jax.device_get(self._evaluate(self.state.agent.params, keys))
        self.counters.last_eval = step
        for i, run in enumerate(self.runs):
            infos = [{"return": float(r), "length": self.loop.episode_steps}
                     for r in results["return"][i][:train.eval_episodes]]
            summary = run.record_eval(step, infos)
            self.progress.write(f"seed {run.seed}: eval  env step {step:>9}: return "
                                f"{summary['return']:.3f} ± {summary['return_std']:.3f} over "
                                f"{len(infos)} episodes")

    def save(self) -> None:
        self.counters.last_ckpt_updates = self.counters.updates
        for i, run in enumerate(self.runs):
            run.save(self.env_steps, self.counters, {"loop": take(self.state, i)})

    def close(self) -> None:
        self.progress.close()
        for run in self.runs:
            run.close()

