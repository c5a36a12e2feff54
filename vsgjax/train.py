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

``train.loop`` picks the loop: this host loop (``host``; the default for gymnasium tasks) or,
for the ``mjx_`` tasks, the fully jitted device loop (``device``, their default;
:mod:`vsgjax.device_train`). The host loop drives the ``mjx_`` tasks too, as one vectorised
env (:mod:`vsgjax.envs.mjx.host`), with vector observations and no videos.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax import checkpoint
from vsgjax.agent import Agent, AgentState
from vsgjax.collect import Collector, EnvBatch, SeedEnvs, make_env_batch
from vsgjax.config import (
    MODELS,
    SIZES,
    Config,
    ConfigError,
    config_changes,
    make_config,
    to_dict,
)
from vsgjax.envs import TaskError, parse_task, resolve_loop
from vsgjax.evaluate import (
    Evaluator,
    acting_policy,
    checkpoint_tree,
    restore_latest,
    summarize,
)
from vsgjax.host import allocator_line
from vsgjax.logger import Logger, Progress, truncate_metrics
from vsgjax.observations import IMAGE_KEY
from vsgjax.parallel import Parallel, mesh_shape, resolve_devices, split_keys, stack, take
from vsgjax.replay import EpisodeStore, Replay
from vsgjax.videos import has_video, open_loop_video

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
                        help="bbs_<variant>, dmc_<domain>_<task>, atari_<game> or "
                             "mjx_<domain>_<task>")
    parser.add_argument("--model", default="vsg", help=f"one of {', '.join(MODELS)}")
    parser.add_argument("--size", default="auto",
                        help=f"auto (small on CPU, paper on GPU) or one of {', '.join(SIZES)}")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", default=None,
                        help="train several seeds in one process, e.g. 0,1,2 (overrides --seed)")
    parser.add_argument("--logdir", default=None,
                        help="default: runs/<task>-<model>-s{seed} ({seed} is filled in)")
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


def parse_seeds(args: argparse.Namespace) -> tuple[list[int], list[str]]:
    """The seeds to train (``--seeds 0,1,2``, ``train.seeds=[0,1,2]`` or ``--seed``) and the
    overrides without ``train.seeds``; raises ConfigError for duplicates or negative seeds."""
    texts = [args.seeds] if args.seeds is not None else []
    overrides = []
    for item in args.overrides:
        key, _, value = item.partition("=")
        if key.strip() == "train.seeds":
            texts.append(value.strip().strip("[]"))
        else:
            overrides.append(item)
    if len(texts) > 1:
        raise ConfigError("give the seeds once: --seeds or train.seeds, not both")
    if not texts:
        return [args.seed], overrides
    try:
        seeds = [int(part) for part in texts[0].split(",")]
    except ValueError:
        raise ConfigError(f"seeds {texts[0]!r}: want comma-separated integers, e.g. 0,1,2"
                          ) from None
    if len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise ConfigError(f"seeds {texts[0]!r}: want distinct integers >= 0, e.g. 0,1,2")
    return seeds, overrides


def build_configs(args: argparse.Namespace, seeds: list[int],
                  overrides: list[str]) -> tuple[list[Config], dict[str, str]]:
    """One resolved config per seed and notes on how size and precision were chosen; raises
    ConfigError/TaskError."""
    size, size_note = resolve_size(args.size)
    precision = []
    precision_note = "as requested"
    if not any(item.partition("=")[0].strip() == "model.precision" for item in overrides):
        precision_note = "default"
        if size == "paper" and has_gpu():
            precision, precision_note = ["model.precision=bfloat16"], "auto: paper size on a GPU"
    configs = [make_config(args.task, args.model, size,
                           [f"train.seed={seed}", *precision, *overrides]) for seed in seeds]
    parse_task(configs[0].env.task)
    return configs, {"size": size_note, "precision": precision_note}


def seed_logdirs(args: argparse.Namespace, seeds: list[int]) -> list[Path]:
    """Each seed's log directory: ``--logdir`` with ``{seed}`` filled in (required for several
    seeds), by default ``runs/<task>-<model>-s<seed>``."""
    pattern = args.logdir or f"runs/{args.task}-{args.model}-s{{seed}}"
    if len(seeds) > 1 and "{seed}" not in pattern:
        raise ConfigError(f"--logdir {pattern!r} must contain {{seed}} when training several "
                          "seeds (one log directory per seed), e.g. runs/bbs-vsg-s{seed}")
    return [Path(pattern.replace("{seed}", str(seed))) for seed in seeds]


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
    """The schedule of a run, shared by its seeds (they train in lockstep); saved in every
    checkpoint, with the seed's own episode count beside it. Thresholds are in env steps."""

    agent_steps: int = 0
    updates: int = 0
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


def non_finite(metrics: dict, update: int, env_steps: int) -> str | None:
    """What is non-finite in an update's metrics (None when everything is finite)."""
    bad = {k: float(v) for k, v in metrics.items() if not math.isfinite(float(v))}
    if not bad:
        return None
    listed = ", ".join(f"{k}={v}" for k, v in sorted(bad.items()))
    return f"non-finite metrics at update {update} (env step {env_steps}): {listed}"


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


def group_label(seeds: list[int]) -> str:
    return ",".join(map(str, seeds))


class RunFiles:
    """One seed's log directory: config, logs, scores, eval records, episode files, checkpoints.

    Each seed of a multi-seed run, and a run of the device loop, writes exactly what a
    single-seed host run writes.
    """

    def __init__(self, config: Config, logdir: Path):
        self.config, self.logdir, self.seed = config, Path(logdir), config.train.seed
        self.logdir.mkdir(parents=True, exist_ok=True)
        self.ckpt_dir = self.logdir / "checkpoints"
        self._check_config()
        self.store = EpisodeStore(self.logdir / "episodes")
        self.scores: dict = {"xs": [], "ys": []}
        self.episodes = 0
        self.checkpoint_path: Path | None = None
        self.window: list[dict] = []  # host metrics of the updates since the last log
        self.window_episodes: list[dict] = []

    def _check_config(self) -> None:
        """A logdir keeps its model and env config; only ``train.*`` may change on resume."""
        path = self.logdir / "config.json"
        if not path.exists() or not checkpoint.list_checkpoints(self.ckpt_dir):
            return
        changed = config_changes(json.loads(path.read_text()), to_dict(self.config))
        if changed:
            raise ConfigError(f"{self.logdir} holds a run with a different config ("
                              + "; ".join(changed) + "); use another --logdir to start a new run")

    def load(self, restored: checkpoint.Checkpoint) -> None:
        self.scores = restored.meta["scores"]
        self.episodes = restored.meta["counters"].get("episodes", 0)
        self.checkpoint_path = restored.path

    def open_logs(self, env_steps: int) -> None:
        """Write config and scores, open the logs (dropping records after ``env_steps``)."""
        checkpoint.atomic_write(self.logdir / "config.json",
                                json.dumps(to_dict(self.config), indent=2).encode())
        # Records an interrupted run wrote after the restored step are dropped.
        self.logger = Logger(self.logdir, resume_step=env_steps)
        truncate_metrics(self.logdir / "eval_episodes.jsonl", env_steps)
        self.write_scores()

    def write_scores(self) -> None:
        record = {"task": self.config.env.task, "method": METHOD_NAMES[self.config.model.name],
                  "seed": str(self.seed), **self.scores}
        checkpoint.atomic_write(self.logdir / "scores.jsonl", (json.dumps(record) + "\n").encode())

    def on_episode(self, episode: dict, info: dict, env_steps: int) -> None:
        self.store.write(episode)
        self.episodes += 1
        self.window_episodes.append(info)
        self.logger.scalars(env_steps, info, prefix="episode")

    def log(self, env_steps: int, shared: dict) -> dict:
        """Write the train record of this log interval (means over its updates); returns it."""
        record = {**shared, "episodes": self.episodes, "replay_steps": self.replay_steps}
        if self.window:
            record.update({k: float(np.mean([m[k] for m in self.window])) for k in self.window[0]})
        if self.window_episodes:
            record["return"] = float(np.mean([e["return"] for e in self.window_episodes]))
        self.logger.scalars(env_steps, record, prefix="train")
        self.window, self.window_episodes = [], []
        return record

    def record_eval(self, step: int, infos: list[dict]) -> dict:
        summary = summarize(infos)
        self.logger.scalars(step, summary, prefix="eval")
        with open(self.logdir / "eval_episodes.jsonl", "a") as file:
            for index, info in enumerate(infos):
                file.write(json.dumps(_json_safe({"step": step, "episode": index, **info})) + "\n")
        self.scores["xs"].append(float(step))
        self.scores["ys"].append(summary["return"])
        self.write_scores()
        return summary

    def save(self, env_steps: int, counters: Counters, tree: dict, **meta) -> None:
        meta = {"counters": {**dataclasses.asdict(counters), "episodes": self.episodes},
                "scores": self.scores, **meta}
        self.checkpoint_path = checkpoint.save(self.ckpt_dir, env_steps, tree, meta,
                                               keep=KEEP_CHECKPOINTS)

    def last_good_checkpoint(self) -> str:
        last = checkpoint.latest(self.ckpt_dir)
        return f"the last good checkpoint is {last}" if last else "no checkpoint was saved yet"

    def close(self) -> None:
        self.logger.close()


class SeedRun(RunFiles):
    """One seed of the host loop: its log directory, replay and evaluation envs."""

    def __init__(self, config: Config, logdir: Path):
        super().__init__(config, logdir)
        train = config.train
        self.replay = Replay(train.replay_capacity, train.length, train.seed, train.oversample_ends)

    @property
    def replay_steps(self) -> int:
        return self.replay.num_steps

    def load(self, restored: checkpoint.Checkpoint) -> None:
        super().load(restored)
        self.replay.rng = checkpoint.rng_from_state(restored.meta["replay_rng"])

    def open(self, agent: Agent, eval_envs: EnvBatch, env_steps: int) -> None:
        """Reload the replay from episodes/, open the logs and the evaluator."""
        # Episodes on disk are data even without a checkpoint (a run killed before its first).
        for episode in self.store.load(limit_steps=self.config.train.replay_capacity):
            self.replay.add_episode(episode)
        self.open_logs(env_steps)
        self.evaluator = Evaluator(agent, eval_envs)

    def on_episode(self, episode: dict, info: dict, env_steps: int) -> None:
        super().on_episode(episode, info, env_steps)
        self.replay.add_episode(episode)

    def save(self, env_steps: int, counters: Counters, state: AgentState, key) -> None:
        super().save(env_steps, counters, checkpoint_tree(state, key),
                     replay_rng=checkpoint.rng_state(self.replay.rng))

    def close(self) -> None:
        self.evaluator.close()
        super().close()


def restore_seeds(runs: list[SeedRun], agent: Agent) -> list[checkpoint.Checkpoint] | None:
    """Every seed's checkpoint of one step (the newest they all have), or None for a new run.

    The seeds save one after the other; a run killed between two saves resumes all of them
    from the step before (``checkpoint.save`` then drops the newer one on the next save).
    """
    def restore(run: SeedRun, max_step: int | None = None):
        return restore_latest(run.ckpt_dir, agent, jax.random.PRNGKey(run.seed), max_step)

    restored = [restore(run) for run in runs]
    if all(c is None for c in restored):
        return None
    missing = [run.seed for run, c in zip(runs, restored, strict=True) if c is None]
    if missing:
        raise ConfigError(
            f"seeds {group_label(missing)} have no checkpoint while the other seeds have one; "
            "the seeds of one process train in lockstep: train them in separate runs")
    step = min(c.step for c in restored)
    restored = [c if c.step == step else restore(run, step)
                for run, c in zip(runs, restored, strict=True)]
    counters = [{k: v for k, v in c.meta["counters"].items() if k != "episodes"} if c else None
                for c in restored]
    if any(c is None or c.step != step for c in restored) or any(
            other != counters[0] for other in counters):
        raise ConfigError(f"seeds {group_label([r.seed for r in runs])} have no common "
                          f"checkpoint to resume from (newest common step {step}); resume them "
                          "in separate runs")
    return restored


class LoopDriver:
    """:meth:`run`: a trainer's ``iteration()`` to ``train.steps``, the final evaluation, the
    checkpoint on SIGINT/SIGTERM and at the end (the host and the device loop share it)."""

    stopped: list[int]  # seeds stopped on non-finite metrics (the trainer sets it)

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
        return self.exit_code()

    def exit_code(self) -> int:
        """1 when seeds stopped early on non-finite metrics (the others finished), else 0."""
        if self.stopped:
            self.out(f"seeds {group_label(self.stopped)} stopped early on non-finite metrics")
            return 1
        return 0

    def _prefix(self, run: RunFiles) -> str:
        """``seed k: `` before a message about one seed, when a run has several."""
        return f"seed {run.seed}: " if len(self.runs) > 1 or self.stopped else ""

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


class Trainer(LoopDriver):
    """A training run of one or more seeds in one process (new or resumed).

    ``configs`` (one per seed, equal but for ``train.seed``) and ``logdirs`` may be a single
    config and directory. The seeds train in lockstep: their states are stacked and updated by
    one vmapped program (:mod:`vsgjax.parallel`), their envs collect together, and each seed
    keeps its own replay, PRNG stream, logs and checkpoints. :meth:`run` trains to the end.
    """

    def __init__(self, configs: Config | Sequence[Config], logdirs: Path | Sequence[Path], *,
                 make_envs: MakeEnvs = make_env_batch, progress: bool = True, out=print):
        self._started = time.monotonic()
        configs = [configs] if isinstance(configs, Config) else list(configs)
        logdirs = [Path(logdirs)] if isinstance(logdirs, str | Path) else list(map(Path, logdirs))
        check_seed_group(configs, logdirs)
        self.config, self.out = configs[0], out
        train, env = self.config.train, self.config.env
        self.devices = resolve_devices(self.config)
        mesh_shape(len(configs), self.devices, train.batch)  # raises if the batch cannot split
        self.runs = [SeedRun(c, d) for c, d in zip(configs, logdirs, strict=True)]
        eval_envs = [make_envs(c.env, c.train.seed, env.eval_envs, eval=True) for c in configs]
        spec = eval_envs[0].spec
        self.agent = Agent(self.config, spec.obs, spec.action_dim, spec.discrete)
        self._said_no_videos = False
        restored = restore_seeds(self.runs, self.agent)
        self.resumed = restored is not None
        if restored is None:
            states = [self.agent.init(jax.random.PRNGKey(run.seed)) for run in self.runs]
            keys = [jax.random.fold_in(jax.random.PRNGKey(run.seed), 1) for run in self.runs]
            self.counters = Counters()
        else:
            states, keys = [c.tree["agent"] for c in restored], [c.tree["key"] for c in restored]
            self.counters = Counters(**{k: v for k, v in restored[0].meta["counters"].items()
                                        if k != "episodes"})
            for run, ckpt in zip(self.runs, restored, strict=True):
                run.load(ckpt)
        for run, envs in zip(self.runs, eval_envs, strict=True):
            run.open(self.agent, envs, self.env_steps)
        self.parallel = Parallel(self.agent, len(self.runs), self.devices)
        self.state = self.parallel.put_state(stack(states))
        self.keys = jnp.stack(keys)
        envs = SeedEnvs([make_envs(run.config.env, env_seed(run.seed, self.counters.agent_steps),
                                   env.num_envs, eval=False) for run in self.runs])
        chunk = max(1, train.train_every // env.num_envs)
        self.collector = Collector(envs, jax.vmap(acting_policy(self.agent, spec, "train")),
                                   chunk=chunk, on_episode=self._on_episode)
        self.carry = stack([self.agent.initial_carry(env.num_envs)] * len(self.runs))
        self.progress = Progress(train.steps, self.env_steps, enabled=progress)
        self._first_update = self.counters.updates + 1  # of this process: it compiles
        self._shown: dict[str, dict[int, float]] = {}  # progress-bar values per seed
        self.stopped: list[int] = []  # seeds stopped on non-finite metrics
        self._last_log_time, self._last_log_step = time.monotonic(), self.env_steps

    @property
    def env_steps(self) -> int:
        return self.counters.agent_steps * self.config.env.action_repeat

    @property
    def seeds(self) -> list[int]:
        return [run.seed for run in self.runs]

    def describe(self) -> str:
        """Whether this run resumes, and from where."""
        per_seed = lambda values: "/".join(str(v) for v in values)
        if not self.resumed:
            found = per_seed(run.replay.num_episodes for run in self.runs)
            found = f" ({found} episodes already in episodes/)" if found.strip("0/") else ""
            seeds = f" of seeds {group_label(self.seeds)}" if len(self.runs) > 1 else ""
            return f"starting a new run{seeds}{found}"
        return (f"resuming from {self.runs[0].checkpoint_path.name}: env step {self.env_steps}, "
                f"update {self.counters.updates}, replay "
                f"{per_seed(run.replay.num_steps for run in self.runs)} steps in "
                f"{per_seed(run.replay.num_episodes for run in self.runs)} episodes")

    # --- the loop ----------------------------------------------------------------------------

    def _next_keys(self) -> jax.Array:
        """One fresh key per seed ``[S, 2]`` from each seed's own stream."""
        self.keys, keys = split_keys(self.keys)
        return keys

    def _show(self, name: str, values: dict[int, float]) -> None:
        """Show ``name`` on the progress bar for the seeds given (one value per seed, / apart)."""
        shown = self._shown.setdefault(name, {})
        shown.update(values)
        self.progress.show({name: [shown.get(seed, math.nan) for seed in self.seeds]})

    @property
    def prefilling(self) -> bool:
        return self.env_steps < self.config.train.prefill or any(
            run.replay.num_sequences == 0 for run in self.runs)

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
        explore = jnp.full((len(self.runs),), self.prefilling)
        # counted first, so episodes finishing in this chunk are logged at its end step
        self.counters.agent_steps += self.collector.chunk * self.collector.envs.num_envs
        self.carry, _ = self.collector.run((self.state.params, explore), self.carry,
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
        c, train = self.counters, self.config.train
        if c.train_start < 0:
            c.train_start = c.agent_steps
            c.next_eval = self.env_steps  # the release evaluates when training starts
            pretrain = f", {train.pretrain} pretraining updates" if train.pretrain else ""
            replay = "/".join(str(run.replay.num_steps) for run in self.runs)
            self.progress.write(
                f"prefill done at env step {self.env_steps} ({replay} steps in replay); "
                "compiling the update (once per process; tens of seconds on a CPU)"
                f"{pretrain}, then training")
        due = train.pretrain + 1 + (c.agent_steps - c.train_start) // train.train_every
        while c.updates < due:
            self.update()

    def update(self) -> None:
        started = time.monotonic()
        batch = self.parallel.put_batch([run.replay.sample(self.config.train.batch)
                                         for run in self.runs])
        self.state, metrics = self.parallel.train_step(self.state, batch, self._next_keys())
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
        return [per_seed[i] for i in keep]

    def maybe_log(self) -> None:
        if self.env_steps < self.counters.next_log:
            return
        self.counters.next_log = next_multiple(self.env_steps, self.config.train.log_every)
        now = time.monotonic()
        shared = {"env_steps_per_s": (self.env_steps - self._last_log_step)
                  / max(now - self._last_log_time, 1e-9), "updates": self.counters.updates}
        records = [run.log(self.env_steps, shared) for run in self.runs]
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
        self._last_log_time, self._last_log_step = now, self.env_steps

    def maybe_evaluate(self) -> None:
        c = self.counters
        if c.train_start >= 0 and self.env_steps >= c.next_eval:
            self.evaluate()
            c.next_eval = next_on_grid(c.next_eval, self.env_steps, self.config.train.eval_every)

    def evaluate(self) -> None:
        """``eval_episodes`` episodes of each seed's actor mode -> scores, episodes, videos."""
        train, step = self.config.train, self.env_steps
        keys = self._next_keys()
        recorded = []
        for i, run in enumerate(self.runs):
            infos, episodes = run.evaluator.run(take(self.state.params, i), train.eval_episodes,
                                                keys[i])
            summary = run.record_eval(step, infos)
            recorded.append(episodes[0])
            self.progress.write(f"{self._prefix(run)}eval  env step {step:>9}: return "
                                f"{summary['return']:.3f} ± {summary['return_std']:.3f} over "
                                f"{len(infos)} episodes")
            self._show("eval", {run.seed: summary["return"]})
        self.counters.last_eval = step
        if step >= self.counters.next_video:
            self.counters.next_video = next_multiple(step, train.video_every)
            self._videos(step, recorded)

    def _videos(self, step: int, recorded: list[dict]) -> None:
        """Each seed's eval and open-loop videos of its first eval episode; for observations
        without images, a note (once per process) instead."""
        if not has_video(recorded[0]):
            if not self._said_no_videos:
                self.progress.write(f"no videos: the observations of {self.config.env.task} "
                                    f"have no image (keys {', '.join(self.agent.obs_shape.keys)})")
                self._said_no_videos = True
            return
        keys = self._next_keys()
        for i, (run, episode) in enumerate(zip(self.runs, recorded, strict=True)):
            run.logger.video("eval", step, episode[IMAGE_KEY])
            frames = open_loop_video(self.config, take(self.state.params["wm"], i), episode,
                                     keys[i])
            if frames is not None:
                run.logger.video("open_loop", step, frames, fps=10)

    def save(self) -> None:
        self.counters.last_ckpt_updates = self.counters.updates
        for i, run in enumerate(self.runs):
            run.save(self.env_steps, self.counters, take(self.state, i), self.keys[i])

    def close(self) -> None:
        self.progress.close()
        self.collector.close()
        for run in self.runs:
            run.close()


def _json_safe(record: dict) -> dict:
    """NaN/inf (e.g. 'never visited' discovery metrics) become null in JSON files."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in record.items()}


def make_trainer(configs: list[Config], logdirs: list[Path], *, progress: bool = True):
    """The host-loop :class:`Trainer` or, for ``train.loop=device``, the device loop's."""
    if resolve_loop(configs[0]) == "device":
        from vsgjax.device_train import DeviceTrainer

        return DeviceTrainer(configs, logdirs, progress=progress)
    return Trainer(configs, logdirs, progress=progress)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        seeds, overrides = parse_seeds(args)
        configs, notes = build_configs(args, seeds, overrides)
        logdirs = seed_logdirs(args, seeds)
        loop = resolve_loop(configs[0])
    except (ConfigError, TaskError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    enable_compilation_cache()
    config = configs[0]
    print(f"vsgjax train: task={config.env.task} model={config.model.name} size={config.size} "
          f"({notes['size']}) {'seeds' if len(seeds) > 1 else 'seed'}={group_label(seeds)} "
          f"steps={config.train.steps} precision={config.model.precision} "
          f"({notes['precision']}) loop={loop}", flush=True)
    print(f"device: {device_line()}\n{allocator_line()}\nlogdir: "
          + ", ".join(map(str, logdirs)), flush=True)
    try:
        trainer = make_trainer(configs, logdirs, progress=not args.no_progress)
    except (ConfigError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    try:
        print(trainer.describe(), flush=True)
        parallel = getattr(trainer, "parallel", None)
        if len(seeds) > 1 or (parallel is not None and parallel.mesh_shape != (1, 1)):
            print(parallel.describe() if parallel else f"{len(seeds)} seeds in one program",
                  flush=True)
        return trainer.run()
    except NonFiniteLossError:  # each seed's reason and last checkpoint are printed already
        return 1
    finally:
        trainer.close()


if __name__ == "__main__":
    sys.exit(main())
