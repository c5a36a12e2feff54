"""Environments built from task names. The families (``bbs_<variant>``,
``dmc_<domain>_<task>``, ``atari_<game>``, ``mjx_<domain>_<task>``) and what each module here
builds are listed in the task-family registry (:mod:`vsgjax.registry.tasks`); a device
family's tasks step inside JAX (the device loop), or in the host loop through their vector
env (``mjx/vector_env.py``).

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

from vsgjax.config import EnvConfig
from vsgjax.envs.spec import EVAL_SEED_OFFSET, EnvSpec, TaskError
from vsgjax.envs.wrappers import DefaultSeed
from vsgjax.episode_keys import IMAGE_DTYPE, VECTOR_DTYPE
from vsgjax.observations import ObsSpec
from vsgjax.registry import resolve
from vsgjax.registry.tasks import FAMILIES, family_of


def parse_task(task: str) -> tuple[str, tuple[str, ...]]:
    """Split and validate a task name through its family (:mod:`vsgjax.registry.tasks`).

    ``dmc_ball_in_cup_catch -> ("dmc", ("ball_in_cup", "catch"))``, ``bbs_basic_d2 -> ("bbs",
    ("basic_d2",))``, ``atari_pong -> ("atari", ("pong",))``.
    """
    family = family_of(task)
    return family.prefix, resolve(family.parse)(task, task.partition("_")[2])


def check_env_config(env_cfg: EnvConfig) -> tuple[str, tuple[str, ...]]:
    """The task's :func:`parse_task`; raises TaskError/ValueError naming a bad task or value."""
    if env_cfg.action_repeat < 1 or env_cfg.time_limit < 1 or env_cfg.image_size < 1:
        raise ValueError(f"action_repeat, time_limit and image_size must be >= 1, got "
                         f"{env_cfg.action_repeat}, {env_cfg.time_limit}, {env_cfg.image_size}")
    family, args = parse_task(env_cfg.task)
    if not FAMILIES[family].grayscale_sticky and (env_cfg.grayscale or env_cfg.sticky):
        raise ValueError(f"grayscale={env_cfg.grayscale} and sticky={env_cfg.sticky} are Atari "
                         f"options; task {env_cfg.task!r} needs grayscale=False and sticky=0")
    return family, args


def make_envs(env_cfg: EnvConfig, seed: int, num_envs: int, *, eval: bool = False
              ) -> list[Callable[[], gymnasium.Env]] | gymnasium.vector.VectorEnv:
    """What a host env batch steps: ``num_envs`` env builders seeded ``seed, seed + 1, ...``
    (picklable, for worker processes), or for the on-device tasks one vectorised env."""
    check_env_config(env_cfg)
    if family_of(env_cfg.task).on_device:
        from vsgjax.envs.mjx.vector_env import MjxVectorEnv, seed_keys

        offset = EVAL_SEED_OFFSET if eval else 0
        return MjxVectorEnv(make_device_task(env_cfg),
                               seed_keys([seed + offset + i for i in range(num_envs)]))
    return [functools.partial(make_env, env_cfg, seed + i, eval=eval) for i in range(num_envs)]


def make_device_task(env_cfg: EnvConfig):
    """The task of a device family (stepped inside JAX: ``reset(key)``, ``step(state,
    action)``), as the device loop and the device vector env step it."""
    family, _ = check_env_config(env_cfg)
    if not FAMILIES[family].on_device:
        raise TaskError(f"{env_cfg.task!r} is a host environment (gymnasium), not a task that "
                        "steps inside JAX")
    return resolve(FAMILIES[family].build)(env_cfg)


def make_env(env_cfg: EnvConfig, seed: int, *, eval: bool = False) -> gymnasium.Env:
    """Build the env named by ``env_cfg.task``; its first ``reset()`` is seeded with ``seed``."""
    family, args = check_env_config(env_cfg)
    if FAMILIES[family].on_device:
        raise TaskError(f"{env_cfg.task!r} steps on the device, not as a gymnasium env; it "
                        "trains with the device loop (train.loop=device or auto) or, through "
                        "its vector env, the host loop (vsgjax.data.collect.make_env_batch)")
    seed = seed + EVAL_SEED_OFFSET if eval else seed
    env = resolve(FAMILIES[family].build)(args, env_cfg, seed, eval)
    env = _normalize_actions(env)
    env_spec(env)  # validates the agent-facing contract
    return DefaultSeed(env, seed)


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
