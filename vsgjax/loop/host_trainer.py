"""The host loop: envs step in Python (:mod:`vsgjax.data.collect`), the updates are one
vmapped program over the seeds (:mod:`vsgjax.loop.parallel`), the replay lives in memory.

Between its steps the shared driver (:mod:`vsgjax.loop.driver`) logs, evaluates and
checkpoints; the loop and its schedule are described in docs/training.md.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.agents import make_agent
from vsgjax.agents.acting import acting_policy
from vsgjax.agents.interface import Agent
from vsgjax.config import Config, ConfigError
from vsgjax.config.checks import max_episode_steps
from vsgjax.data import checkpoint
from vsgjax.data.collect import Collector, EnvBatch, SeedEnvs, make_env_batch
from vsgjax.data.replay import Replay
from vsgjax.envs import EnvSpec
from vsgjax.episode_keys import IMAGE_KEY
from vsgjax.loop.driver import (
    FirstUpdate,
    LoopDriver,
    SeedEval,
    check_first_update,
    check_seed_group,
    group_label,
    non_finite,
    open_runs,
    restore_seeds,
    saved_counters,
    unlock_runs,
)
from vsgjax.loop.evaluator import Evaluator
from vsgjax.loop.gate_logging import logs_gates
from vsgjax.loop.memory_check import check_fits, host_replay_steps, host_step_bytes, tree_bytes
from vsgjax.loop.parallel import Parallel, mesh_shape, resolve_devices, split_keys, stack, take
from vsgjax.loop.run_state import checkpoint_tree, restore_latest
from vsgjax.loop.rundir import RunWriter
from vsgjax.loop.schedule import Counters, env_seed
from vsgjax.registry.tasks import family_of

MakeEnvs = Callable[..., EnvBatch]  # (env_cfg, seed, num_envs, *, eval) -> EnvBatch
# Shown on the progress bar after every update: the world-model loss and the per-pixel image
# error, which falls visibly from the first updates (the image loss is dominated by a constant).
PER_UPDATE = {"loss": "wm/loss", "mse": "wm/image_mse"}


def first_update(config: Config) -> FirstUpdate:
    """When the host loop's first update comes: after the collection chunk in which prefill
    ends and every env has finished an episode (the replay samples finished episodes only),
    an episode running to its time limit unless the family's episodes end early as a rule."""
    env, train = config.env, config.train
    chunk = max(1, train.train_every // env.num_envs)  # agent steps of each env per chunk
    per_chunk = chunk * env.num_envs * env.action_repeat  # env steps
    chunks = max(1, -(-train.prefill // per_chunk))
    why = [f"prefill ends at env step {chunks * per_chunk} (train.prefill={train.prefill})"]
    if not family_of(env.task).ends_early:
        episode = max_episode_steps(config) - 1  # agent steps
        episode_chunks = -(-episode // chunk)
        why.append(f"the first episodes end at env step {episode_chunks * per_chunk} "
                   f"({episode} agent steps with env.time_limit={env.time_limit}, "
                   f"env.action_repeat={env.action_repeat}, env.num_envs={env.num_envs})")
        chunks = max(chunks, episode_chunks)
    return FirstUpdate(chunks * per_chunk, (chunks - 1) * per_chunk + 1, "; ".join(why))


class SeedRun(RunWriter):
    """One seed of the host loop: its run directory, replay and evaluation envs."""

    def __init__(self, config: Config, logdir: Path, *, restart: bool = False,
                 prepare: bool = True):
        super().__init__(config, logdir, restart=restart, prepare=prepare)
        self._replay_rng = config.train.seed  # the restored stream when the run resumes

    @property
    def replay_steps(self) -> int:
        return self.replay.num_steps

    def load(self, restored: checkpoint.Checkpoint) -> None:
        super().load(restored)
        self._replay_rng = checkpoint.rng_from_state(restored.meta["replay_rng"])

    def open(self, agent: Agent, eval_envs: EnvBatch) -> None:
        """Make the replay the agent samples from, reload it from episodes/ and open the
        evaluator."""
        train, needs = self.config.train, agent.replay
        self.replay = Replay(train.replay_capacity, needs.length, self._replay_rng,
                             train.oversample_ends, history=needs.history)
        # the episodes up to the checkpoint (RunWriter moved those after it aside)
        for episode in self.store.load(limit_steps=self.config.train.replay_capacity):
            self.replay.add_episode(episode)
        self.evaluator = Evaluator(agent, eval_envs)

    def on_episode(self, episode: dict, info: dict, env_steps: int) -> None:
        super().on_episode(episode, info, env_steps)
        self.replay.add_episode(episode)

    def close(self) -> None:
        self.evaluator.close()
        super().close()


class HostTrainer(LoopDriver):
    """A training run of one or more seeds in one process (new or resumed).

    ``configs`` (one per seed, equal but for ``train.seed``) and ``logdirs`` may be a single
    config and directory. The seeds train in lockstep: their states are stacked and updated by
    one vmapped program, their envs collect together, and each seed keeps its own replay, PRNG
    stream, logs and checkpoints. :meth:`run` trains to the end.
    """

    def __init__(self, configs: Config | Sequence[Config], logdirs: Path | Sequence[Path], *,
                 make_envs: MakeEnvs = make_env_batch, progress: bool = True, out=print,
                 restart: bool = False):
        self._started = time.monotonic()
        configs = [configs] if isinstance(configs, Config) else list(configs)
        logdirs = [Path(logdirs)] if isinstance(logdirs, str | Path) else list(map(Path, logdirs))
        check_seed_group(configs, logdirs)
        self.config, self.out = configs[0], out
        self.devices = resolve_devices(self.config)
        mesh_shape(len(configs), self.devices, self.config.train.batch)  # the batch must split
        check_first_update(self.config, logdirs, first_update(self.config), restart=restart)
        eval_envs = [make_envs(c.env, c.train.seed, self.config.env.eval_envs, eval=True)
                     for c in configs]
        try:
            self.agent = make_agent(self.config, eval_envs[0].spec)
            self._check_memory(len(configs), eval_envs[0].spec)
            self.runs = open_runs(lambda c, d: SeedRun(c, d, restart=restart, prepare=False),
                                  configs, logdirs)
        except BaseException:
            for envs in eval_envs:
                envs.close()
            raise
        try:
            self._set_up(eval_envs, make_envs, progress)
        except BaseException:
            unlock_runs(self.runs)
            raise

    def _check_memory(self, seeds: int, spec: EnvSpec) -> None:
        """Refuse a run whose agent states and replays cannot fit (:mod:`memory_check`)."""
        state = jax.eval_shape(self.agent.init, jax.random.PRNGKey(0))
        steps = host_replay_steps(self.config, max_episode_steps(self.config))
        check_fits(self.config, seeds, {"agent state": tree_bytes(state)},
                   {"replay": steps * host_step_bytes(spec)})

    def _set_up(self, eval_envs: list[EnvBatch], make_envs: MakeEnvs, progress: bool) -> None:
        """The restored (or fresh) state of every seed, its replay, the collector."""
        train, env = self.config.train, self.config.env
        self._said_no_videos = False

        def restore(run: SeedRun, max_step: int | None):
            return restore_latest(run.ckpt_dir, self.agent, jax.random.PRNGKey(run.seed),
                                  max_step)

        restored = restore_seeds(self.runs, restore)
        self.resumed = restored is not None
        if restored is None:
            states = [self.agent.init(jax.random.PRNGKey(run.seed)) for run in self.runs]
            keys = [jax.random.fold_in(jax.random.PRNGKey(run.seed), 1) for run in self.runs]
            counters = Counters()
        else:
            states, keys = [c.tree["agent"] for c in restored], [c.tree["key"] for c in restored]
            counters = saved_counters(restored[0])
            for run, ckpt in zip(self.runs, restored, strict=True):
                run.load(ckpt)
        for run, envs in zip(self.runs, eval_envs, strict=True):
            run.open(self.agent, envs)
        self.start(counters, progress=progress)
        self.parallel = Parallel(self.agent, len(self.runs), self.devices)
        self.state = self.parallel.put_state(stack(states))
        self.keys = jnp.stack(keys)
        envs = SeedEnvs([make_envs(run.config.env, env_seed(run.seed, self.counters.agent_steps),
                                   env.num_envs, eval=False) for run in self.runs])
        chunk = max(1, train.train_every // env.num_envs)
        self._acting_params = jax.jit(jax.vmap(self.agent.acting_params))
        self.collector = Collector(envs, jax.vmap(acting_policy(self.agent, "train")),
                                   chunk=chunk, on_episode=self._on_episode)
        self.carry = stack([self.agent.initial_carry(env.num_envs)] * len(self.runs))
        self.last_batch: dict | None = None  # the latest update's batch [S, B, T, ...]
        self._first_update = self.counters.updates + 1  # of this process: it compiles

    def describe(self) -> str:
        """Whether this run resumes, and from where."""
        per_seed = lambda values: "/".join(str(v) for v in values)
        if not self.resumed:
            seeds = f" of seeds {group_label(self.seeds)}" if len(self.runs) > 1 else ""
            return f"starting a new run{seeds}"
        return (f"resuming from {self.runs[0].checkpoint_path.name}: env step {self.env_steps}, "
                f"update {self.counters.updates}, replay "
                f"{per_seed(run.replay.num_steps for run in self.runs)} steps in "
                f"{per_seed(run.replay.num_episodes for run in self.runs)} episodes")

    def parallel_line(self) -> str | None:
        if len(self.runs) > 1 or self.parallel.mesh_shape != (1, 1):
            return self.parallel.describe()
        return None

    # --- the loop ----------------------------------------------------------------------------

    def _next_keys(self) -> jax.Array:
        """One fresh key per seed ``[S, 2]`` from each seed's own stream."""
        self.keys, keys = split_keys(self.keys)
        return keys

    @property
    def prefilling(self) -> bool:
        return self.env_steps < self.config.train.prefill or any(
            run.replay.num_sequences == 0 for run in self.runs)

    def step(self) -> None:
        """A chunk of collection, then the updates due."""
        self.collect()
        self.train_due()

    def collect(self) -> None:
        """One chunk of agent steps with the training policy (random while prefilling)."""
        explore = jnp.full((len(self.runs),), self.prefilling)
        # counted first, so episodes finishing in this chunk are logged at its end step
        self.counters.agent_steps += self.collector.chunk * self.collector.envs.num_envs
        self.carry, _ = self.collector.run((self._acting_params(self.state), explore), self.carry,
                                           self._next_keys())
        self.progress.update(self.env_steps)

    def _on_episode(self, episode: dict, index: int, info: dict) -> None:
        run = self.runs[index // self.collector.envs.num_envs]
        run.on_episode(episode, info, self.env_steps)
        self._show("ret", {run.seed: info["return"]})

    def train_due(self) -> None:
        """The updates owed at the train ratio (the first one as soon as prefill ends)."""
        if self.prefilling:
            return
        train = self.config.train
        if not self.schedule.training:
            self.schedule.start_training()
            pretrain = f", {train.pretrain} pretraining updates" if train.pretrain else ""
            replay = "/".join(str(run.replay.num_steps) for run in self.runs)
            self.progress.write(
                f"prefill done at env step {self.env_steps} ({replay} steps in replay); "
                "compiling the update (once per process; tens of seconds on a CPU)"
                f"{pretrain}, then training")
        due = self.schedule.updates_due()
        while self.counters.updates < due:
            self.update()

    def update(self) -> None:
        started = time.monotonic()
        batch = self.parallel.put_batch([run.replay.sample(self.config.train.batch)
                                         for run in self.runs])
        self.state, metrics = self.parallel.train_step(self.state, batch, self._next_keys())
        self.last_batch = batch
        metrics = jax.device_get(metrics)
        per_seed = [{k: v[i] for k, v in metrics.items()} for i in range(len(self.runs))]
        problems = [non_finite(m, self.counters.updates + 1, self.env_steps) for m in per_seed]
        if any(problems):
            per_seed = self._stop_seeds(problems, per_seed)
        self.counters.updates += 1
        for run, seed_metrics in zip(self.runs, per_seed, strict=True):
            run.window.append(seed_metrics)
        if self.counters.updates == self._first_update:
            self.progress.write(
                f"update {self.counters.updates} took {time.monotonic() - started:.0f} s with "
                f"its compilation ({time.monotonic() - self._started:.0f} s after start)")
        # the latest update's losses on the bar, between the averaged log lines
        self.progress.show({"upd": self.counters.updates})
        for short, key in PER_UPDATE.items():
            if key in per_seed[0]:
                self._show(short, {run.seed: m[key]
                                   for run, m in zip(self.runs, per_seed, strict=True)})

    def _stop_seeds(self, problems: list[str | None], per_seed: list[dict]) -> list[dict]:
        """Stop the seeds whose update was non-finite (their state is not kept); the others go
        on. Raises NonFiniteLossError when none is left. Returns the metrics of those kept."""
        keep = self._stop_runs(problems)
        self.collector.drop_seeds(keep)
        try:
            self.parallel = Parallel(self.agent, len(keep), self.devices)
        except ConfigError:  # the batch no longer splits over the devices left to each seed
            self.parallel = Parallel(self.agent, len(keep), math.gcd(len(keep), self.devices))
        self.state = self.parallel.put_state(take(self.state, keep))
        self.keys, self.carry = self.keys[jnp.asarray(keep)], take(self.carry, keep)
        self.last_batch = None  # of the seeds before; the next update sets it again
        return [per_seed[i] for i in keep]

    def log(self) -> None:
        """The train records, then each seed's ``gates/*`` line on its latest training batch
        (:mod:`vsgjax.loop.gate_logging`)."""
        super().log()
        if logs_gates(self.agent) and self.last_batch is not None:
            for i, run in enumerate(self.runs):
                summary = self.agent.gate_summary(take(self.state, i), take(self.last_batch, i))
                run.logger.scalars(self.env_steps, summary)

    def report_log(self, records: list[dict], shared: dict) -> None:
        shown = {"ret": "return", **PER_UPDATE, "rew": "wm/reward_loss", "kl": "wm/kl",
                 "actor": "actor/loss", "critic": "critic/loss"}
        shown = {short: [r.get(key, math.nan) for r in records] for short, key in shown.items()
                 if any(key in r for r in records)}
        for short, values in shown.items():
            self._show(short, dict(zip(self.seeds, values, strict=True)))
        if not self.progress.enabled:  # a line per log instead of the bar
            parts = [f"updates {self.counters.updates}",
                     f"{shared['env_steps_per_s']:.1f} steps/s",
                     *(f"{short} " + "/".join(f"{v:.3g}" for v in values)
                       for short, values in shown.items())]
            self.progress.write(f"train env step {self.env_steps:>9}: " + ", ".join(parts))

    def eval_episodes(self) -> list[SeedEval]:
        """``train.eval_episodes`` episodes of each seed's actor mode in its eval envs; the
        first is recorded, and an agent with the ``open_loop_errors`` hook (a world model) gives
        its open-loop errors on it (key: ``fold_in`` of the seed's evaluation key, so the
        seeds' key streams are the same with and without the hook)."""
        keys, params = self._next_keys(), self._acting_params(self.state)
        errors = getattr(self.agent, "open_loop_errors", None)
        results = []
        for i, run in enumerate(self.runs):
            infos, episodes = run.evaluator.run(take(params, i),
                                                self.config.train.eval_episodes, keys[i])
            open_loop = None
            if errors is not None:
                batch = {k: np.asarray(v)[None] for k, v in episodes[0].items()}
                open_loop = errors(take(self.state, i), batch, jax.random.fold_in(keys[i], 1))
                open_loop = None if open_loop is None else jax.device_get(open_loop)
            results.append(SeedEval(infos, episodes[0], open_loop))
        return results

    def videos(self, step: int, recorded: list[dict]) -> None:
        """Each seed's eval video of its first eval episode, and its open-loop video when the
        agent has a world model; for observations without images, a note (once per process)
        instead."""
        if IMAGE_KEY not in recorded[0]:
            if not self._said_no_videos:
                self.progress.write(f"no videos: the observations of {self.config.env.task} "
                                    f"have no image (keys {', '.join(self.agent.obs_shape.keys)})")
                self._said_no_videos = True
            return
        keys, open_loop = self._next_keys(), getattr(self.agent, "open_loop_video", None)
        for i, (run, episode) in enumerate(zip(self.runs, recorded, strict=True)):
            run.logger.video("eval", step, episode[IMAGE_KEY])
            frames = open_loop and open_loop(take(self.state, i), episode, keys[i])
            if frames is not None:
                run.logger.video("open_loop", step, frames, fps=10)

    def checkpoint_of(self, index: int) -> tuple[dict, dict]:
        tree = checkpoint_tree(take(self.state, index), self.keys[index])
        return tree, {"replay_rng": checkpoint.rng_state(self.runs[index].replay.rng)}

    def close_loop(self) -> None:
        self.collector.close()
