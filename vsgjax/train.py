"""``make train`` / ``python -m vsgjax.train``: the command line of training.

    python -m vsgjax.train --task bbs_basic --model vsg --size auto --seed 0 \\
        --logdir runs/bbs_basic-vsg-s0 train.steps=50000 wm.kl_scale=0.3

It resolves the configs (one per seed) and runs the trainer of the task's loop:
:class:`~vsgjax.loop.host_trainer.HostTrainer` (``train.loop=host``) or
:class:`~vsgjax.loop.device_trainer.DeviceTrainer` (``train.loop=device``, the ``mjx_``
tasks' default). The loop, its schedule and resuming are described in docs/training.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax

from vsgjax.allocator import allocator_line
from vsgjax.config import MODELS, SIZES, Config, ConfigError, make_config
from vsgjax.config.checks import RANGES
from vsgjax.data.checkpoint import WriteError
from vsgjax.envs import TaskError, make_device_task, parse_task
from vsgjax.envs.backgrounds import check_videos
from vsgjax.loop.device_trainer import DeviceTrainer
from vsgjax.loop.driver import LoopDriver, NonFiniteLossError, group_label
from vsgjax.loop.host_trainer import HostTrainer
from vsgjax.loop.rundir import EPISODES_DIR, RunWriter
from vsgjax.loop.which_loop import resolve_loop
from vsgjax.registry.agents import DEFAULT_MODEL
from vsgjax.registry.tasks import DEFAULT_TASK, VECTOR, family_of, patterns

COMPILATION_CACHE = Path.home() / ".cache" / "vsgjax" / "xla"


# --- command line ------------------------------------------------------------------------------


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m vsgjax.train",
        description="Train a world-model agent (see `make train`).",
        epilog="Overrides are dotted config keys, e.g. train.steps=50000 wm.kl_scale=0.3.")
    parser.add_argument("--task", default=DEFAULT_TASK, help=patterns())
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"one of {', '.join(MODELS)}")
    parser.add_argument("--size", default="auto",
                        help="auto (paper on a GPU; on a CPU cpu for mjx_ tasks, small for the "
                             f"others) or one of {', '.join(SIZES)}")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", default=None,
                        help="train several seeds in one process, e.g. 0,1,2 (overrides --seed)")
    parser.add_argument("--logdir", default=None,
                        help="default: runs/<task>-<model>-s{seed} ({seed} is filled in)")
    parser.add_argument("--restart", action="store_true",
                        help="start over in a log directory that holds a run: its old contents "
                             "are moved to <logdir>/previous/<UTC time>/ (nothing is deleted)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("overrides", nargs="*", metavar="key=value")
    return parser.parse_args(argv)


def has_gpu() -> bool:
    return any(device.platform == "gpu" for device in jax.devices())


def resolve_size(size: str, task: str) -> tuple[str, str]:
    """(size, why): ``auto`` becomes ``paper`` when JAX sees a GPU, else ``cpu`` for the tasks
    with vector observations (``mjx_``) and ``small`` for the others."""
    if size != "auto":
        return size, "as requested"
    if has_gpu():
        return "paper", "auto: JAX sees a GPU"
    if family_of(task).observations == VECTOR:
        return "cpu", "auto: no GPU, vector observations"
    return "small", "auto: no GPU"


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
        if args.seed not in RANGES["train.seed"]:
            raise ConfigError(f"--seed {args.seed}: valid: an integer in {RANGES['train.seed']}")
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
    size, size_note = resolve_size(args.size, args.task)
    precision = []
    precision_note = "as requested"
    if not any(item.partition("=")[0].strip() == "model.precision" for item in overrides):
        precision_note = "default"
        if size == "paper" and has_gpu():
            precision, precision_note = ["model.precision=bfloat16"], "auto: paper size on a GPU"
    configs = [make_config(args.task, args.model, size,
                           [f"train.seed={seed}", *precision, *overrides]) for seed in seeds]
    parse_task(configs[0].env.task)
    if family_of(args.task).on_device:  # its options are checked against the task's keys
        make_device_task(configs[0].env)
    if configs[0].env.background == "video":  # videos that decode, for both splits
        check_videos(configs[0].env.background_dir)
    return configs, {"size": size_note, "precision": precision_note}


def seed_logdirs(args: argparse.Namespace, seeds: list[int]) -> list[Path]:
    """Each seed's log directory: ``--logdir`` with ``{seed}`` filled in (required for several
    seeds), by default ``runs/<task>-<model>-s<seed>``."""
    if args.logdir is not None and not args.logdir.strip():
        raise ConfigError(f"--logdir {args.logdir!r} is empty; give a directory, or leave "
                          f"--logdir out for runs/{args.task}-{args.model}-s{{seed}}")
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


TRAINERS = {"host": HostTrainer, "device": DeviceTrainer}


def make_trainer(configs: list[Config], logdirs: list[Path], *, progress: bool = True,
                 restart: bool = False) -> LoopDriver:
    """The trainer of the configs' loop (``train.loop``, resolved by the task); ``restart``
    moves what the log directories hold aside first."""
    return TRAINERS[resolve_loop(configs[0])](configs, logdirs, progress=progress,
                                              restart=restart)


def set_aside_lines(runs: list[RunWriter]) -> list[str]:
    """What opening the run directories found and moved aside (nothing is deleted): the old
    contents (``--restart``), another run's checkpoints, a killed attempt, the episodes after
    the checkpoint; and a config rebuilt from a checkpoint."""
    lines = []
    for run in runs:
        if run.moved_to is not None:
            lines.append(f"--restart: moved the old contents of {run.logdir} to {run.moved_to}")
        if run.config_from is not None:
            lines.append(f"{run.logdir}: config.json is missing: the run's config is rebuilt "
                         f"from {run.config_from.name}, the config it was trained with")
        for path, target, why in run.foreign_moved:
            lines.append(f"{path} is not this run's checkpoint ({why}): moved it to {target}; "
                         "the run resumes from its own newest checkpoint")
        if run.attempt_moved_to is not None:
            lines.append(f"{run.logdir} held an attempt killed before its first checkpoint "
                         f"and evaluation: moved what it wrote to {run.attempt_moved_to}; "
                         "starting over")
        if run.episodes_moved_to is not None:
            moved = len(list((run.episodes_moved_to / EPISODES_DIR).glob("*.mcap")))
            lines.append(f"{run.logdir}: moved {moved} episode file(s) written after "
                         f"{run.checkpoint_path.name} by the interrupted run to "
                         f"{run.episodes_moved_to / EPISODES_DIR} (not in the replay)")
    return lines


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
    print(f"vsgjax train: task={config.env.task} model={config.agent} size={config.size} "
          f"({notes['size']}) {'seeds' if len(seeds) > 1 else 'seed'}={group_label(seeds)} "
          f"steps={config.train.steps} precision={config.precision} "
          f"({notes['precision']}) loop={loop}", flush=True)
    print(f"device: {device_line()}\n{allocator_line()}\nlogdir: "
          + ", ".join(map(str, logdirs)), flush=True)
    print(f"overrides: {' '.join(overrides) if overrides else 'none (the presets as they are)'}",
          flush=True)
    try:
        trainer = make_trainer(configs, logdirs, progress=not args.no_progress,
                               restart=args.restart)
    except WriteError as error:  # the file written before is intact
        print(f"error: {error}", file=sys.stderr)
        return 1
    except (ConfigError, ValueError) as error:  # RunDirError, OutputDirError: nothing changed
        print(f"error: {error}", file=sys.stderr)
        return 2
    try:
        for line in set_aside_lines(trainer.runs):
            print(line, flush=True)
        print(trainer.describe(), flush=True)
        line = trainer.parallel_line()
        if line:
            print(line, flush=True)
        return trainer.run()
    except NonFiniteLossError:  # each seed's reason and last checkpoint are printed already
        return 1
    except WriteError as error:  # the file written before is intact
        print(f"error: {error}", file=sys.stderr)
        return 1
    finally:
        trainer.close()


if __name__ == "__main__":
    sys.exit(main())
