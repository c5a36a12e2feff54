"""Task registry: one name scheme for every environment family of the paper.

==========================  ==========================================================
``bbs_<variant>``           BringBackShapes (``bbs`` package), the 16 paper variants
``dmc_<domain>_<task>``     DeepMind Control Suite, rendered 64x64 RGB (see ``dmc.py``)
``atari_<game>``            Atari through ale-py, DreamerV2 settings (see ``atari.py``)
``mjx_<domain>_<task>``     DeepMind Control on MuJoCo MJX, vector observations, stepped on
                            the device by the jitted loop (``mjx/``; not a gymnasium env)
==========================  ==========================================================

Every env made here is a ``gymnasium.Env`` whose observation is a uint8 image ``(H, W, C)``
(C=3, or 1 for grayscale Atari) and whose action space is ``Box(-1, 1, (A,), float32)`` or
``Discrete(n)`` (the agent acts with one-hot vectors; ``vsgjax.collect`` converts). Action
repeat and the time limit come from ``EnvConfig`` (``time_limit`` counts env steps, before
action repeat). ``make_env(cfg, seed)`` returns an env whose first ``reset()`` is seeded with
``seed``; evaluation envs (``eval=True``) draw from a disjoint seed range.
"""

from __future__ import annotations

from typing import NamedTuple

import gymnasium
import numpy as np

from vsgjax.config import EnvConfig
from vsgjax.envs.wrappers import DefaultSeed

TASK_PATTERNS = ("bbs_<variant>", "dmc_<domain>_<task>", "atari_<game>", "mjx_<domain>_<task>")
DEVICE_FAMILIES = ("mjx",)  # tasks that step inside JAX (vsgjax/device_loop.py), not gymnasium
EVAL_SEED_OFFSET = 1_000_000  # eval env seeds are seed + offset, never a training env's seed


class TaskError(ValueError):
    """An unknown or malformed task name; the message lists what is valid."""


class EnvSpec(NamedTuple):
    """What the model needs to know about an env, as plain values."""

    obs_shape: tuple[int, int, int]
    action_dim: int
    discrete: bool


def parse_task(task: str) -> tuple[str, tuple[str, ...]]:
    """Split and validate a task name.

    ``dmc_ball_in_cup_catch -> ("dmc", ("ball_in_cup", "catch"))``, ``bbs_basic_d2 -> ("bbs",
    ("basic_d2",))``, ``atari_pong -> ("atari", ("pong",))``.
    """
    family, sep, rest = task.partition("_")
    if not sep or not rest or family not in _PARSERS:
        raise TaskError(f"unknown task {task!r}; valid patterns: {', '.join(TASK_PATTERNS)}")
    return family, _PARSERS[family](task, rest)


def _parse_bbs(task: str, variant: str) -> tuple[str]:
    from vsgjax.envs.bbs_task import variant_names

    return (_one_of(task, variant, variant_names(), "bbs", "BringBackShapes variant"),)


def _parse_dmc(task: str, rest: str) -> tuple[str, str]:
    from vsgjax.envs.dmc import all_tasks

    pairs = all_tasks()
    for domain, name in pairs:
        if f"{domain}_{name}" == rest:
            return domain, name
    raise TaskError(f"unknown DMC task {task!r}; valid: "
                    + ", ".join(f"dmc_{d}_{t}" for d, t in pairs))


def _parse_atari(task: str, game: str) -> tuple[str]:
    from vsgjax.envs.atari import all_games

    return (_one_of(task, game, all_games(), "atari", "Atari game"),)


def _one_of(task: str, name: str, valid, family: str, what: str) -> str:
    """``name`` if it is in ``valid``, else a TaskError listing the valid task names."""
    if name not in valid:
        raise TaskError(f"unknown {what} in {task!r}; valid: "
                        + ", ".join(f"{family}_{v}" for v in valid))
    return name


def _parse_mjx(task: str, rest: str) -> tuple[str]:
    from vsgjax.envs.mjx import parse_mjx_task

    parse_mjx_task(task)
    return (rest,)


_PARSERS = {"bbs": _parse_bbs, "dmc": _parse_dmc, "atari": _parse_atari, "mjx": _parse_mjx}


def make_env(env_cfg: EnvConfig, seed: int, *, eval: bool = False) -> gymnasium.Env:
    """Build the env named by ``env_cfg.task``; its first ``reset()`` is seeded with ``seed``."""
    if env_cfg.action_repeat < 1 or env_cfg.time_limit < 1 or env_cfg.image_size < 1:
        raise ValueError(f"action_repeat, time_limit and image_size must be >= 1, got "
                         f"{env_cfg.action_repeat}, {env_cfg.time_limit}, {env_cfg.image_size}")
    family, args = parse_task(env_cfg.task)
    if family in DEVICE_FAMILIES:
        raise TaskError(f"{env_cfg.task!r} steps on the device, not as a gymnasium env; it "
                        "trains with the device loop (train.loop=device or auto)")
    if family != "atari" and (env_cfg.grayscale or env_cfg.sticky):
        raise ValueError(f"grayscale={env_cfg.grayscale} and sticky={env_cfg.sticky} are Atari "
                         f"options; task {env_cfg.task!r} needs grayscale=False and sticky=0")
    seed = seed + EVAL_SEED_OFFSET if eval else seed
    env = _BUILDERS[family](args, env_cfg, seed)
    env = _normalize_actions(env)
    env_spec(env)  # validates the agent-facing contract
    return DefaultSeed(env, seed)


def _build_bbs(args: tuple[str], cfg: EnvConfig, seed: int) -> gymnasium.Env:
    from vsgjax.envs.bbs_task import make_bbs

    return make_bbs(args[0], action_repeat=cfg.action_repeat, time_limit=cfg.time_limit,
                    size=cfg.image_size)


def _build_dmc(args: tuple[str, str], cfg: EnvConfig, seed: int) -> gymnasium.Env:
    from vsgjax.envs.dmc import DMCEnv

    return DMCEnv(*args, action_repeat=cfg.action_repeat, time_limit=cfg.time_limit,
                  size=cfg.image_size, seed=seed)


def _build_atari(args: tuple[str], cfg: EnvConfig, seed: int) -> gymnasium.Env:
    from vsgjax.envs.atari import make_atari

    return make_atari(args[0], action_repeat=cfg.action_repeat, time_limit=cfg.time_limit,
                      size=cfg.image_size, grayscale=cfg.grayscale, sticky=cfg.sticky)


_BUILDERS = {"bbs": _build_bbs, "dmc": _build_dmc, "atari": _build_atari}


def _normalize_actions(env: gymnasium.Env) -> gymnasium.Env:
    """Rescale a bounded Box action space to [-1, 1] when it is not already."""
    space = env.action_space
    if isinstance(space, gymnasium.spaces.Box) and not (
            np.all(space.low == -1.0) and np.all(space.high == 1.0)):
        env = gymnasium.wrappers.RescaleAction(env, np.float32(-1.0), np.float32(1.0))
    return env


def env_spec(env: gymnasium.Env | gymnasium.vector.VectorEnv) -> EnvSpec:
    """The plain (obs_shape, action_dim, discrete) of an env; raises if it breaks the contract."""
    obs_space = getattr(env, "single_observation_space", env.observation_space)
    act_space = getattr(env, "single_action_space", env.action_space)
    if not (isinstance(obs_space, gymnasium.spaces.Box) and obs_space.dtype == np.uint8
            and len(obs_space.shape) == 3):
        raise TypeError(f"observation space must be a uint8 (H, W, C) Box, got {obs_space}")
    if isinstance(act_space, gymnasium.spaces.Discrete):
        return EnvSpec(tuple(obs_space.shape), int(act_space.n), True)
    if isinstance(act_space, gymnasium.spaces.Box) and len(act_space.shape) == 1:
        return EnvSpec(tuple(obs_space.shape), int(act_space.shape[0]), False)
    raise TypeError(f"action space must be Discrete or a 1-d Box, got {act_space}")
