"""The driver of ``train.loop=device``: one call of the compiled program
(:class:`~vsgjax.loop.device_program.DeviceProgram`) per iteration, the shared driver between.

Each call is K episodes of every env of every seed with the updates due inside it (K = 1
but for a family whose sequences cross episodes); between calls the driver writes the same run
directory as the host loop, one episode file per finished episode (no videos: the device tasks
have no pixels; the open-loop errors of an agent with a world model are computed inside the
compiled evaluation, on its evaluation episodes). The checkpoint holds the whole program state
(agent, device replay, PRNG key); the envs need none, since every episode starts by resetting
them.
"""

from __future__ import annotations

import functools
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.config import Config, ConfigError
from vsgjax.data import checkpoint
from vsgjax.envs import make_device_task
from vsgjax.loop.device_program import DeviceProgram, LoopState
from vsgjax.loop.driver import (
    LoopDriver,
    SeedEval,
    check_first_update,
    check_seed_group,
    non_finite,
    open_runs,
    restore_seeds,
    saved_counters,
    unlock_runs,
)
from vsgjax.loop.gate_logging import logs_gates, probe_key
from vsgjax.loop.memory_check import check_fits, tree_bytes
from vsgjax.loop.parallel import resolve_devices, seed_batched, seed_sharding, stack, take
from vsgjax.loop.rundir import RunWriter
from vsgjax.loop.schedule import Counters


@functools.cache
def jitted_programs(program: DeviceProgram, seeds: int, devices: int) -> tuple:
    """``({training: episode call}, pretrain, evaluate)`` over ``seeds`` stacked seeds, jitted
    with the seed axis spread over ``devices`` (:func:`~vsgjax.loop.parallel.seed_sharding`);
    one set per program in a process, so a resumed trainer reuses its compilations."""
    train = program.config.train
    spread = seed_sharding(seeds, devices)

    def jit(function):
        return jax.jit(seed_batched(function, seeds), in_shardings=spread, out_shardings=spread)

    episode = {training: jit(lambda state, training=training: program.episode(state, training))
               for training in (False, True)}
    pretrain = jit(lambda state: program.pretrain(state, train.pretrain))
    evaluate = jit(lambda state, key: program.evaluate(state, key, train.eval_episodes))
    return episode, pretrain, evaluate


class DeviceTrainer(LoopDriver):
    """Train one or more seeds of a device task with the compiled device program."""

    def __init__(self, configs: list[Config], logdirs: list[Path], *, progress: bool = True,
                 out=print, restart: bool = False):
        check_seed_group(configs, logdirs)
        self.config, self.out = configs[0], out
        self.program = DeviceProgram(self.config, make_device_task(self.config.env))
        self.program.check()
        check_first_update(self.config, logdirs, self.program.first_update(), restart=restart)
        self.devices = resolve_devices(self.config)
        if len(configs) % self.devices:
            raise ConfigError(f"train.devices={self.devices} does not divide the {len(configs)} "
                              "seeds: the device loop spreads whole seeds over the devices; "
                              f"valid: a divisor of {len(configs)}")
        state = jax.eval_shape(self.program.init, jax.random.PRNGKey(0))
        check_fits(self.config, len(configs) // self.devices,  # the seeds of one device
                   {"agent state": tree_bytes(state.agent), "replay": tree_bytes(state.replay)})
        self.runs = open_runs(lambda c, d: RunWriter(c, d, restart=restart, prepare=False),
                              configs, logdirs)
        try:
            self._compile(len(self.runs))
            self._sample = jax.jit(self.program.sample)
            self.state, counters, self.resumed = self._restore()
            self.start(counters, progress=progress)
        except BaseException:
            unlock_runs(self.runs)
            raise
        self._update_replay_steps()

    def _compile(self, seeds: int) -> None:
        """The jitted programs of ``seeds`` stacked seeds (again after seeds stop)."""
        episode, self._pretrain, self._evaluate = jitted_programs(self.program, seeds,
                                                                  self.devices)
        self._episode = dict(episode)
        self._called: set[bool] = set()  # the calls compiled so far (prefill: False)

    def _restore(self) -> tuple[LoopState, Counters, bool]:
        def restore(run: RunWriter, max_step: int | None):
            target = jax.eval_shape(self.program.init, jax.random.PRNGKey(run.seed))
            return checkpoint.restore(run.ckpt_dir, {"loop": target}, max_step)

        restored = restore_seeds(self.runs, restore)
        if restored is None:
            states = [self.program.init(jax.random.PRNGKey(run.seed)) for run in self.runs]
            return self._place(stack(states)), Counters(), False
        for run, ckpt in zip(self.runs, restored, strict=True):
            run.load(ckpt)
        return (self._place(stack([c.tree["loop"] for c in restored])),
                saved_counters(restored[0]), True)

    def _place(self, state: LoopState) -> LoopState:
        """The stacked state with its seeds spread over the program's devices."""
        return jax.device_put(state, seed_sharding(len(self.runs), self.devices))

    def describe(self) -> str:
        program = self.program
        episodes = program.episodes_per_call
        what = (f"device loop: {self.config.env.num_envs} envs x "
                + (f"{episodes} episodes of " if episodes > 1 else "")
                + f"{program.episode_steps} agent steps per call, {program.updates_per_call} "
                f"updates per call once trained, replay of {program.replay_episodes} "
                + ("row" if episodes > 1 else "episode") + " batches")
        if not self.resumed:
            return f"starting a new run; {what}"
        return (f"resuming from {self.runs[0].checkpoint_path.name}: env step {self.env_steps}, "
                f"update {self.counters.updates}; {what}")

    def parallel_line(self) -> str | None:
        if len(self.runs) == 1:
            return None
        devices = math.gcd(len(self.runs), self.devices)
        return f"{len(self.runs)} seeds in one program" + (
            f", spread over {devices} devices" if devices > 1 else "")

    def _update_replay_steps(self) -> None:
        stored = np.asarray(self.state.replay.stored)
        per_batch = self.config.env.num_envs * self.program.row_steps
        for run, count in zip(self.runs, stored, strict=True):
            run.replay_steps = int(min(count, self.program.replay_episodes)) * per_batch

    # --- the loop ----------------------------------------------------------------------------

    @property
    def prefilling(self) -> bool:
        """Until prefill has ended and the replay holds an episode batch to sample."""
        return self.env_steps < max(self.config.train.prefill, 1)

    def step(self) -> None:
        """One call of the compiled program: K episodes of every env (and their updates)."""
        c = self.counters
        training = not self.prefilling
        if training and not self.schedule.training:
            self._start_training()
        if training not in self._called:
            self._called.add(training)
            self.progress.write(f"compiling the {'training' if training else 'prefill'} call: "
                                "policy, physics, replay"
                                f"{' and updates' if training else ''} in one XLA program "
                                "(minutes on a CPU the first time; the compilation cache keeps "
                                "it for later runs)")
        started = time.monotonic()
        self.state, metrics, records = self._episode[training](self.state)
        records = jax.device_get(records)
        c.agent_steps += self.config.env.num_envs * self.program.agent_steps_per_call
        if training:
            keep = self._take_metrics(jax.device_get(metrics), self.program.updates_per_call)
            records = {k: v[keep] for k, v in records.items()}
        self._update_replay_steps()
        self._write_episodes(records)
        self.progress.update(self.env_steps)
        self.progress.show({"call_s": time.monotonic() - started, "upd": c.updates})

    def _start_training(self) -> None:
        train = self.config.train
        self.schedule.start_training()
        self.progress.write(f"prefill done at env step {self.env_steps}; "
                            f"{train.pretrain} pretraining updates")
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
        self._compile(len(keep))
        self.state = self._place(take(self.state, keep))
        return keep

    def _write_episodes(self, records: dict) -> None:
        """Every env's finished episodes (a row ``[K (E + 1)]`` split into K) -> its seed's
        episodes/ and episode metrics."""
        steps = self.program.episode_steps + 1
        for i, run in enumerate(self.runs):
            for env in range(self.config.env.num_envs):
                for start in range(0, self.program.row_steps, steps):
                    episode = {k: np.asarray(v[i, env, start:start + steps])
                               for k, v in records.items()}
                    info = {"return": float(episode["reward"].sum()),
                            "length": len(episode["reward"]) - 1}
                    run.on_episode(episode, info, self.env_steps, numbered=True)

    def log(self) -> None:
        """The train records, then each seed's ``gates/*`` line on a batch of its replay
        (:mod:`vsgjax.loop.gate_logging`)."""
        super().log()
        if logs_gates(self.program.agent) and self.schedule.training:
            for i, run in enumerate(self.runs):
                summary = self.program.agent.gate_summary(
                    take(self.state.agent, i), self.gate_batch(i),
                    memory_gap=getattr(self.program.task, "memory_gap", 0))
                run.logger.scalars(self.env_steps, summary)

    def gate_batch(self, index: int) -> dict:
        """The batch of seed ``index``'s ``gates/*`` line at this env step: ``train.batch``
        sequences sampled from its replay with :func:`~vsgjax.loop.gate_logging.probe_key`."""
        key = probe_key(self.runs[index].seed, self.env_steps)
        return self._sample(take(self.state.replay, index), key)

    def report_log(self, records: list[dict], shared: dict) -> None:
        returns = "/".join(f"{r['return']:.3g}" for r in records if "return" in r)
        self.progress.write(f"train env step {self.env_steps:>9}: updates "
                            f"{self.counters.updates}, return {returns}")

    def eval_episodes(self) -> list[SeedEval]:
        """Each seed's ``train.eval_episodes`` episodes of one compiled call, with its agent's
        open-loop errors on them (:meth:`DeviceProgram.evaluate`)."""
        step, episodes = self.env_steps, self.config.train.eval_episodes
        keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(run.seed), step)
                          for run in self.runs])
        results = jax.device_get(self._evaluate(self.state.agent, keys))
        open_loop = results.get("open_loop")
        return [SeedEval([{"return": float(r), "length": self.program.episode_steps}
                          for r in results["return"][i][:episodes]], None,
                         None if open_loop is None else take(open_loop, i))
                for i in range(len(self.runs))]

    def checkpoint_of(self, index: int) -> tuple[dict, dict]:
        return {"loop": take(self.state, index)}, {}
