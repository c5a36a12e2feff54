"""``make train`` / ``python -m vsgjax.train``: collect, train, evaluate, checkpoint, resume.

    python -m vsgjax.train --task bbs_basic --model vsg --size auto --seed 0 \\
        --logdir runs/bbs_basic-vsg-s0 train.steps=50000 wm.kl_scale=0.3

The loop, with the train ratio of the spec (one update per ``train.train_every`` agent steps)::

    prefill: random actions until train.prefill env steps AND the replay holds a sequence
    then train.pretrain updates at once (the release's pretraining), and an evaluation
    until train.steps env steps:
        collect a chunk of agent steps (policy on device, envs on host)   -> replay, episodes/
        run the updates now due (pretrain + 1 + agent steps since prefill // train_every)
        every log_every env steps   -> metrics.jsonl, TensorBoard, progress bar
        every eval_every env steps  -> eval episodes: scores.jsonl, eval_episodes.jsonl,
        (counted from the end of        videos/ (at the first eval after every video_every)
         prefill, as the release)
        every ckpt_every updates, on SIGINT/SIGTERM and at the end -> checkpoints/

Env steps count action repeat (agent steps x ``env.action_repeat``). Rerunning the same command
on the same ``--logdir`` resumes from the newest checkpoint: agent state, PRNG key, counters,
replay sampler state and scores come back, and the replay is reloaded from ``episodes/``; the
episodes that were unfinished when the run stopped are lost. A non-finite loss stops training
with a message naming the update and the metrics, without checkpointing that state.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax import checkpoint
from vsgjax.agent import Agent
from vsgjax.collect import Collector, EnvBatch, make_env_batch
from vsgjax.config import (
    MODELS,
    SIZES,
    Config,
    ConfigError,
    config_changes,
    make_config,
    to_dict,
)
from vsgjax.envs import TaskError, parse_task
from vsgjax.evaluate import (
    Evaluator,
    acting_policy,
    checkpoint_tree,
    restore_latest,
    summarize,
)
from vsgjax.host import allocator_line
from vsgjax.logger import Logger, Progress, truncate_metrics
from vsgjax.replay import EpisodeStore, Replay
from vsgjax.videos import open_loop_video

METHOD_NAMES = {"dreamerv1": "DreamerV1", "dreamerv2": "DreamerV2", "vsg": "VSG",
                "svsg": "SVSG", "ssm": "SSM"}  # as in ../shared/reference_scores
KEEP_CHECKPOINTS = 3
# Shown on the progress bar after every update: the world-model loss and the per-pixel image
# error, which falls visibly from the first updates (the image loss is dominated by a constant).
PER_UPDATE = {"loss": "wm/loss", "mse": "wm/image_mse"}

COMPILATION_CACHE = Path.home() / ".cache" / "vsgjax" / "xla"
MakeEnvs = Callable[..., EnvBatch]  # (env_cfg, seed, num_envs, *, eval) -> EnvBatch


class NonFiniteLossError(RuntimeError):
    """An update produced a NaN or infinite metric; its state was not kept."""


# --- command line ------------------------------------------------------------------------------


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m vsgjax.train",
        description="Train a world-model agent (see `make train`).",
        epilog="Overrides are dotted config keys, e.g. train.steps=50000 wm.kl_scale=0.3.")
    parser.add_argument("--task", default="bbs_basic",
                        help="bbs_<variant>, dmc_<domain>_<task> or atari_<game>")
    parser.add_argument("--model", default="vsg", help=f"one of {', '.join(MODELS)}")
    parser.add_argument("--size", default="auto",
                        help=f"auto (small on CPU, paper on GPU) or one of {', '.join(SIZES)}")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--logdir", type=Path, default=None,
                        help="default: runs/<task>-<model>-s<seed>")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("overrides", nargs="*", metavar="key=value")
    return parser.parse_args(argv)


def has_gpu() -> bool:
    return any(device.platform == "gpu" for device in jax.devices())


def resolve_size(size: str) -> tuple[str, str]:
    """(size, why): ``auto`` becomes ``paper`` when JAX sees a GPU, else ``small``."""
    if size != "auto":
        return size, "as requested"
    return ("paper", "auto: JAX sees a GPU") if has_gpu() else ("small", "auto: no GPU")


def build_config(args: argparse.Namespace) -> tuple[Config, str]:
    """The resolved config and a note on how the size was chosen; raises ConfigError/TaskError."""
    size, why = resolve_size(args.size)
    config = make_config(args.task, args.model, size, [f"train.seed={args.seed}", *args.overrides])
    parse_task(config.env.task)
    return config, why


def enable_compilation_cache() -> None:
    """Reuse compiled programs across runs, so a resumed run skips most compilation.

    ``JAX_COMPILATION_CACHE_DIR`` (read by JAX itself) overrides the location.
    """
    if not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", str(COMPILATION_CACHE))


def device_line() -> str:
    device = jax.devices()[0]
    return f"{device.platform} ({device.device_kind}, {jax.device_count()} device(s))"


# --- run state ---------------------------------------------------------------------------------


@dataclasses.dataclass
class Counters:
    """Progress of a run; saved in every checkpoint. Thresholds are in env steps."""

    agent_steps: int = 0
    updates: int = 0
    episodes: int = 0
    train_start: int = -1  # agent step at which training began (-1 while prefilling)
    next_log: int = 0
    next_eval: int = 0  # the end of prefill, then every train.eval_every env steps after it
    next_video: int = 0
    last_eval: int = -1  # env step of the latest evaluation
    last_ckpt_updates: int = 0


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


def check_finite(metrics: dict, update: int, env_steps: int) -> None:
    bad = {k: float(v) for k, v in metrics.items() if not math.isfinite(float(v))}
    if bad:
        listed = ", ".join(f"{k}={v}" for k, v in sorted(bad.items()))
        raise NonFiniteLossError(
            f"non-finite metrics at update {update} (env step {env_steps}): {listed}")


class Trainer:
    """One training run in ``logdir`` (new or resumed); :meth:`run` trains to the end."""

    def __init__(self, config: Config, logdir: Path, *, make_envs: MakeEnvs = make_env_batch,
                 progress: bool = True, out=print):
        self._started = time.monotonic()
        self.config, self.logdir, self.out = config, Path(logdir), out
        train = config.train
        self.logdir.mkdir(parents=True, exist_ok=True)
        self.ckpt_dir = self.logdir / "checkpoints"
        self._check_config()
        eval_envs = make_envs(config.env, train.seed, config.env.eval_envs, eval=True)
        spec = eval_envs.spec
        self.agent = Agent(config, spec.obs_shape, spec.action_dim, spec.discrete)
        self.evaluator = Evaluator(self.agent, eval_envs)
        self.key = jax.random.PRNGKey(train.seed)
        restored = restore_latest(self.ckpt_dir, self.agent, self.key)
        self.resumed = restored is not None
        self.replay = Replay(train.replay_capacity, train.length, train.seed, train.oversample_ends)
        self.store = EpisodeStore(self.logdir / "episodes")
        self.scores = {"xs": [], "ys": []}
        if restored is None:
            self.state = self.agent.init(self.key)
            self.counters = Counters()
            self.key = jax.random.fold_in(self.key, 1)
        else:
            self._load(restored)
        # Episodes on disk are data even without a checkpoint (a run killed before its first).
        for episode in self.store.load(limit_steps=train.replay_capacity):
            self.replay.add_episode(episode)
        self._write_config()
        # Records an interrupted run wrote after the restored step are dropped.
        self.logger = Logger(self.logdir, resume_step=self.env_steps)
        truncate_metrics(self.logdir / "eval_episodes.jsonl", self.env_steps)
        self._write_scores()
        envs = make_envs(config.env, env_seed(train.seed, self.counters.agent_steps),
                         config.env.num_envs, eval=False)
        chunk = max(1, train.train_every // config.env.num_envs)
        self.collector = Collector(envs, acting_policy(self.agent, spec, "train"), chunk=chunk,
                                   on_episode=self._on_episode)
        self.carry = self.agent.initial_carry(config.env.num_envs)
        self.progress = Progress(train.steps, self.env_steps, enabled=progress)
        self._first_update = self.counters.updates + 1  # of this process: it compiles
        self._window: list[dict] = []  # host metrics of the updates since the last log
        self._window_episodes: list[dict] = []
        self._last_log_time, self._last_log_step = time.monotonic(), self.env_steps

    # --- setup -------------------------------------------------------------------------------

    def _check_config(self) -> None:
        """A logdir keeps its model and env config; only ``train.*`` may change on resume."""
        path = self.logdir / "config.json"
        if not path.exists() or not checkpoint.list_checkpoints(self.ckpt_dir):
            return
        changed = config_changes(json.loads(path.read_text()), to_dict(self.config))
        if changed:
            raise ConfigError(f"{self.logdir} holds a run with a different config ("
                              + "; ".join(changed) + "); use another --logdir to start a new run")

    def _write_config(self) -> None:
        text = json.dumps(to_dict(self.config), indent=2)
        checkpoint.atomic_write(self.logdir / "config.json", text.encode())

    def _load(self, restored: checkpoint.Checkpoint) -> None:
        self.state, self.key = restored.tree["agent"], restored.tree["key"]
        meta = restored.meta
        self.counters = Counters(**meta["counters"])
        self.replay.rng = checkpoint.rng_from_state(meta["replay_rng"])
        self.scores = meta["scores"]
        self.checkpoint_path = restored.path

    @property
    def env_steps(self) -> int:
        return self.counters.agent_steps * self.config.env.action_repeat

    def describe(self) -> str:
        """Whether this run resumes, and from where."""
        if not self.resumed:
            found = f" ({self.replay.num_episodes} episodes already in episodes/)" if \
                self.replay.num_episodes else ""
            return f"starting a new run{found}"
        return (f"resuming from {self.checkpoint_path.name}: env step {self.env_steps}, update "
                f"{self.counters.updates}, replay {self.replay.num_steps} steps in "
                f"{self.replay.num_episodes} episodes")

    # --- the loop ----------------------------------------------------------------------------

    def _next_key(self) -> jax.Array:
        self.key, key = jax.random.split(self.key)
        return key

    @property
    def prefilling(self) -> bool:
        return self.env_steps < self.config.train.prefill or self.replay.num_sequences == 0

    def run(self) -> int:
        """Train to ``train.steps`` env steps; returns the process exit code."""
        train = self.config.train
        with checkpoint.StopSignal() as stop:
            while self.env_steps < train.steps and not stop.requested:
                self.iteration()
            if not stop.requested and self.counters.last_eval != self.env_steps:
                self.evaluate()  # the final score
            self.save()
        self.progress.close()
        if stop.requested:
            name = signal.Signals(stop.received).name
            self.out(f"{name}: saved a checkpoint at env step {self.env_steps}; rerun the "
                     "same command to resume")
            return 128 + stop.received
        self.out(f"done: {self.env_steps} env steps, {self.counters.updates} updates")
        return 0

    def iteration(self) -> None:
        """One pass of the loop: a chunk of collection, the updates due, logs, eval, checkpoint."""
        self.collect()
        self.train_due()
        self.maybe_log()
        self.maybe_evaluate()
        if self.counters.updates >= self.counters.last_ckpt_updates + self.config.train.ckpt_every:
            self.save()

    def collect(self) -> None:
        """One chunk of agent steps with the training policy (random while prefilling)."""
        explore = jnp.asarray(self.prefilling)
        # counted first, so episodes finishing in this chunk are logged at its end step
        self.counters.agent_steps += self.collector.chunk * self.collector.envs.num_envs
        self.carry, _ = self.collector.run((self.state.params, explore), self.carry,
                                           self._next_key())
        self.progress.update(self.env_steps)

    def _on_episode(self, episode: dict, index: int, info: dict) -> None:
        self.store.write(episode)
        self.replay.add_episode(episode)
        self.counters.episodes += 1
        self._window_episodes.append(info)
        self.logger.scalars(self.env_steps, info, prefix="episode")
        self.progress.show({"ret": info["return"]})

    def train_due(self) -> None:
        """The updates owed at the train ratio (the first one as soon as prefill ends)."""
        if self.prefilling:
            return
        c, train = self.counters, self.config.train
        if c.train_start < 0:
            c.train_start = c.agent_steps
            c.next_eval = self.env_steps  # the release evaluates when training starts
            pretrain = f", {train.pretrain} pretraining updates" if train.pretrain else ""
            self.progress.write(
                f"prefill done at env step {self.env_steps} ({self.replay.num_steps} steps in "
                "replay); compiling the update (once per process; tens of seconds on a CPU)"
                f"{pretrain}, then training")
        due = train.pretrain + 1 + (c.agent_steps - c.train_start) // train.train_every
        while c.updates < due:
            self.update()

    def update(self) -> None:
        started = time.monotonic()
        batch = self.replay.sample(self.config.train.batch)
        state, metrics = self.agent.train_step(self.state, batch, self._next_key())
        metrics = jax.device_get(metrics)
        check_finite(metrics, self.counters.updates + 1, self.env_steps)
        self.state = state
        self.counters.updates += 1
        self._window.append(metrics)
        if self.counters.updates == self._first_update:
            self.progress.write(
                f"update {self.counters.updates} took {time.monotonic() - started:.0f} s with "
                f"its compilation ({time.monotonic() - self._started:.0f} s after start)")
        # the latest update's losses on the bar, between the averaged log lines
        self.progress.show({"upd": self.counters.updates,
                            **{short: metrics[k] for short, k in PER_UPDATE.items()
                               if k in metrics}})

    def maybe_log(self) -> None:
        if self.env_steps < self.counters.next_log:
            return
        self.counters.next_log = next_multiple(self.env_steps, self.config.train.log_every)
        now = time.monotonic()
        record = {"env_steps_per_s": (self.env_steps - self._last_log_step)
                  / max(now - self._last_log_time, 1e-9),
                  "updates": self.counters.updates, "episodes": self.counters.episodes,
                  "replay_steps": self.replay.num_steps}
        if self._window:
            record.update({k: float(np.mean([m[k] for m in self._window]))
                           for k in self._window[0]})
        if self._window_episodes:
            record["return"] = float(np.mean([e["return"] for e in self._window_episodes]))
        self.logger.scalars(self.env_steps, record, prefix="train")
        shown = {"ret": "return", **PER_UPDATE, "rew": "wm/reward_loss", "kl": "wm/kl",
                 "actor": "actor/loss", "critic": "critic/loss"}
        values = {short: record[k] for short, k in shown.items() if k in record}
        self.progress.show(values)
        if not self.progress.enabled:  # a line per log instead of the bar
            parts = [f"updates {self.counters.updates}",
                     f"{record['env_steps_per_s']:.1f} steps/s",
                     *(f"{k} {v:.3g}" for k, v in values.items())]
            self.progress.write(f"train env step {self.env_steps:>9}: " + ", ".join(parts))
        self._window, self._window_episodes = [], []
        self._last_log_time, self._last_log_step = now, self.env_steps

    def maybe_evaluate(self) -> None:
        c = self.counters
        if c.train_start >= 0 and self.env_steps >= c.next_eval:
            self.evaluate()
            c.next_eval = next_on_grid(c.next_eval, self.env_steps, self.config.train.eval_every)

    def evaluate(self) -> None:
        """``eval_episodes`` episodes of the actor's mode -> scores, episode metrics, videos."""
        train, step = self.config.train, self.env_steps
        infos, episodes = self.evaluator.run(self.state.params, train.eval_episodes,
                                             self._next_key())
        summary = summarize(infos)
        self.counters.last_eval = step
        self.logger.scalars(step, summary, prefix="eval")
        with open(self.logdir / "eval_episodes.jsonl", "a") as file:
            for index, info in enumerate(infos):
                file.write(json.dumps(_json_safe({"step": step, "episode": index, **info})) + "\n")
        self.scores["xs"].append(float(step))
        self.scores["ys"].append(summary["return"])
        self._write_scores()
        self.progress.write(f"eval  env step {step:>9}: return {summary['return']:.3f} "
                            f"± {summary['return_std']:.3f} over {len(infos)} episodes")
        self.progress.show({"eval": summary["return"]})
        if step >= self.counters.next_video:
            self.counters.next_video = next_multiple(step, train.video_every)
            self.logger.video("eval", step, episodes[0]["image"])
            frames = open_loop_video(self.config, self.state.params["wm"], episodes[0],
                                     self._next_key())
            if frames is not None:
                self.logger.video("open_loop", step, frames, fps=10)

    def _write_scores(self) -> None:
        record = {"task": self.config.env.task, "method": METHOD_NAMES[self.config.model.name],
                  "seed": str(self.config.train.seed), **self.scores}
        checkpoint.atomic_write(self.logdir / "scores.jsonl", (json.dumps(record) + "\n").encode())

    def save(self) -> None:
        self.counters.last_ckpt_updates = self.counters.updates
        meta = {"counters": dataclasses.asdict(self.counters),
                "replay_rng": checkpoint.rng_state(self.replay.rng), "scores": self.scores}
        self.checkpoint_path = checkpoint.save(self.ckpt_dir, self.env_steps,
                                               checkpoint_tree(self.state, self.key), meta,
                                               keep=KEEP_CHECKPOINTS)

    def close(self) -> None:
        self.progress.close()
        self.collector.close()
        self.evaluator.close()
        self.logger.close()


def _json_safe(record: dict) -> dict:
    """NaN/inf (e.g. 'never visited' discovery metrics) become null in JSON files."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in record.items()}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        config, size_note = build_config(args)
    except (ConfigError, TaskError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    enable_compilation_cache()
    logdir = args.logdir or Path("runs") / f"{args.task}-{args.model}-s{args.seed}"
    print(f"vsgjax train: task={config.env.task} model={config.model.name} size={config.size} "
          f"({size_note}) seed={config.train.seed} steps={config.train.steps}", flush=True)
    print(f"device: {device_line()}\n{allocator_line()}\nlogdir: {logdir}", flush=True)
    try:
        trainer = Trainer(config, logdir, progress=not args.no_progress)
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    try:
        print(trainer.describe(), flush=True)
        return trainer.run()
    except NonFiniteLossError as error:
        last = checkpoint.latest(trainer.ckpt_dir)
        kept = f"the last good checkpoint is {last}" if last else "no checkpoint was saved yet"
        print(f"error: training stopped: {error}; the non-finite state was not saved; {kept}",
              file=sys.stderr)
        return 1
    finally:
        trainer.close()


if __name__ == "__main__":
    sys.exit(main())
