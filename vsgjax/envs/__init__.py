"""Task registry: one name scheme for every environment family of the paper.

==========================  ==========================================================
``bbs_<variant>``           BringBackShapes (``bbs`` package), the 16 paper variants
``dmc_<domain>_<task>``     DeepMind Control Suite, rendered 64x64 RGB (see ``dmc.py``)
``atari_<game>``            Atari through ale-py, DreamerV2 settings (see ``atari.py``)
``mjx_<domain>_<task>``     DeepMind Control on MuJoCo MJX, vector observations, stepped on
                            the device (``mjx/``; not a gymnasium env: the device loop
                            runs them, the host loop through ``mjx/host.py``'s vector env)
==========================  ==========================================================

Every env made here is a ``gymnasium.Env`` whose observation is a uint8 image ``(H, W, C)``
(C=3, or 1 for grayscale Atari) and whose action space is ``Box(-1, 1, (A,), float32)`` or
``Discrete(n)`` (the agent acts with one-hot vectors; ``vsgjax.data.collect`` converts). Action
repeat and the time limit come from ``EnvConfig`` (``time_limit`` counts env steps, before
action repeat). ``make_env(cfg, seed)`` returns an env whose first ``reset()`` is seeded with
``seed``; evaluation envs (``eval=True``) draw from a disjoint seed range (``seed +
EVAL_SEED_OFFSET``). The host loop also takes gymnasium vector envs with observation *dicts*
(MJX: ``{"vector": float32 (D,)}``); :func:`env_spec` reads both kinds.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import gymnasium
import numpy as np

from vsgjax.config import Config, ConfigError, EnvConfig
from vsgjax.envs.spec import EVAL_SEED_OFFSET, EnvSpec, TaskError
from vsgjax.envs.wrappers import DefaultSeed
from vsgjax.keys import IMAGE_DTYPE, VECTOR_DTYPE
from vsgjax.model.observations import ObsSpec

TASK_PATTERNS = ("bbs_<variant>", "dmc_<domain>_<task>", "atari_<game>", "mjx_<domain>_<task>")
DEVICE_FAMILIES = ("mjx",)  # tasks that step inside JAX (loop/device_program.py), not gymnasium


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


def check_env_config(env_cfg: EnvConfig) -> tuple[str, tuple[str, ...]]:
    """The task's :func:`parse_task`; raises TaskError/ValueError naming a bad task or value."""
    if env_cfg.action_repeat < 1 or env_cfg.time_limit < 1 or env_cfg.image_size < 1:
        raise ValueError(f"action_repeat, time_limit and image_size must be >= 1, got "
                         f"{env_cfg.action_repeat}, {env_cfg.time_limit}, {env_cfg.image_size}")
    family, args = parse_task(env_cfg.task)
    if family != "atari" and (env_cfg.grayscale or env_cfg.sticky):
        raise ValueError(f"grayscale={env_cfg.grayscale} and sticky={env_cfg.sticky} are Atari "
                         f"options; task {env_cfg.task!r} needs grayscale=False and sticky=0")
    return family, args


def make_envs(env_cfg: EnvConfig, seed: int, num_envs: int, *, eval: bool = False
              ) -> list[Callable[[], gymnasium.Env]] | gymnasium.vector.VectorEnv:
    """What a host env batch steps: ``num_envs`` env builders seeded ``seed, seed + 1, ...``
    (picklable, for worker processes), or for the on-device tasks one vectorised env."""
    family, _ = check_env_config(env_cfg)
    if family in DEVICE_FAMILIES:
        from vsgjax.envs.mjx.vector_env import make_mjx_vector_env

        offset = EVAL_SEED_OFFSET if eval else 0
        return make_mjx_vector_env(env_cfg, [seed + offset + i for i in range(num_envs)])
    return [functools.partial(make_env, env_cfg, seed + i, eval=eval) for i in range(num_envs)]


def make_env(env_cfg: EnvConfig, seed: int, *, eval: bool = False) -> gymnasium.Env:
    """Build the env named by ``env_cfg.task``; its first ``reset()`` is seeded with ``seed``."""
    family, args = check_env_config(env_cfg)
    if family in DEVICE_FAMILIES:
        raise TaskError(f"{env_cfg.task!r} steps on the device, not as a gymnasium env; it "
                        "trains with the device loop (train.loop=device or auto) or, through "
                        "its vector env, the host loop (vsgjax.data.collect.make_env_batch)")
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
    obs_shape = _obs_shape(obs_space)
    if isinstance(act_space, gymnasium.spaces.Discrete):
        return EnvSpec(obs_shape, int(act_space.n), True)
    if isinstance(act_space, gymnasium.spaces.Box) and len(act_space.shape) == 1:
        return EnvSpec(obs_shape, int(act_space.shape[0]), False)
    raise TypeError(f"action space must be Discrete or a 1-d Box, got {act_space}")


_OBS_CONTRACT = ("a uint8 (H, W, C) Box, or a Dict of observation keys (uint8 (H, W, C) "
                 "images, float32 (D,) vectors)")


def _obs_shape(space: gymnasium.Space) -> tuple[int, int, int] | ObsSpec:
    """An image Box's shape, or the ObsSpec of a Dict space; TypeError otherwise."""
    if _is_image(space):
        return tuple(space.shape)
    if isinstance(space, gymnasium.spaces.Dict) and all(
            _is_image(s) or _is_vector(s) for s in space.spaces.values()):
        try:
            return ObsSpec.from_dict({key: s.shape for key, s in space.spaces.items()})
        except ValueError as error:
            raise TypeError(f"observation space {space}: {error}") from None
    raise TypeError(f"observation space must be {_OBS_CONTRACT}, got {space}")


def _is_image(space: gymnasium.Space) -> bool:
    return (isinstance(space, gymnasium.spaces.Box) and space.dtype == IMAGE_DTYPE
            and len(space.shape) == 3)


def _is_vector(space: gymnasium.Space) -> bool:
    return (isinstance(space, gymnasium.spaces.Box) and space.dtype == VECTOR_DTYPE
            and len(space.shape) == 1)


def resolve_loop(config: Config) -> str:
    """``host`` or ``device`` for ``train.loop`` (``auto``: device for tasks that step in JAX,
    which the host loop drives too, through their vector env); raises ConfigError for the
    device loop on a host task."""
    task, loop = config.env.task, config.train.loop
    on_device = task.partition("_")[0] in DEVICE_FAMILIES  # the family; the name is checked
    # where the env is made (a test's own task names, e.g. dmc_reach, are host tasks)
    if loop == "auto":
        return "device" if on_device else "host"
    if loop == "device" and not on_device:
        raise ConfigError("train.loop=device needs a task that steps inside JAX ("
                          + ", ".join(f"{f}_*" for f in DEVICE_FAMILIES) + f"); {task!r} is a "
                          "host environment (gymnasium, stepped in Python): use train.loop=host "
                          "or auto")
    return loop
