"""DeepMind Control Suite tasks in pure JAX on MuJoCo MJX (``mjx_<domain>_<task>``).

The physics is dm_control's own XML, compiled by MuJoCo and copied to MJX; reward functions,
observations and initial-state randomisation are dm_control's, written in JAX. Everything is a
pure function of a pytree state, so a batch of environments is ``jax.vmap`` and a rollout is
``jax.lax.scan``::

    task = make_mjx_task("mjx_cartpole_swingup", action_repeat=2, time_limit=1000)
    state = jax.jit(task.reset)(key)
    state = jax.jit(task.step)(state, action)  # action in [-1, 1]^task.action_dim

Changes to the suite's models (all in ``core.load_model`` or a domain's ``edit``):

* ``cartpole.xml`` and ``pendulum.xml`` enable MuJoCo's ``energy`` flag, which MJX rejects;
  it is cleared. Energy is a diagnostic: no force, observation or reward reads it.
* Per-episode model edits of dm_control become state (reacher's target position lives in
  ``state.info``) or are made once when they are the same every episode (reacher's target
  size, finger spin's hinge damping).

:class:`vsgjax.envs.mjx.vector_env.MjxVectorEnv` presents N envs as one gymnasium vector env,
for the host training loop (``train.loop=host``); the device loop
(``vsgjax/loop/device_program.py``) steps them inside its own jitted program.

See ``docs/mjx.md`` for the tasks, the measured agreement with dm_control and the API.
"""

from __future__ import annotations

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    # mujoco.mjx prints "Failed to import warp" to stdout where the optional MuJoCo Warp
    # backend is not installed (it is not used here); keep the training log's stdout clean.
    from mujoco import mjx  # noqa: F401

from vsgjax.envs.mjx import cartpole, cheetah, finger, hopper, pendulum, reacher, walker
from vsgjax.envs.mjx.core import MjxState, MjxTask, TaskSpec, physics
from vsgjax.envs.spec import TaskError
from vsgjax.registry.names import did_you_mean

__all__ = ["MjxState", "MjxTask", "TaskSpec", "make_mjx_task", "mjx_task_names",
           "parse_mjx_task", "physics"]

_DOMAINS = (cartpole, pendulum, reacher, cheetah, walker, finger, hopper)
SPECS: dict[str, TaskSpec] = {spec.name: spec for module in _DOMAINS
                              for spec in module.TASKS.values()}


def mjx_task_names() -> list[str]:
    """Every ``mjx_<domain>_<task>`` name, in registry order."""
    return list(SPECS)


def parse_mjx_task(name: str) -> TaskSpec:
    """The spec named ``name``; a TaskError listing every valid mjx task name otherwise."""
    if name not in SPECS:
        hint = did_you_mean(name.removeprefix("mjx_"), [s.removeprefix("mjx_") for s in SPECS],
                            prefix="mjx_")
        raise TaskError(f"unknown MJX task {name!r}{hint}; valid: {', '.join(SPECS)}")
    return SPECS[name]


def make_mjx_task(name: str, action_repeat: int = 2, time_limit: int = 1000) -> MjxTask:
    """The task ``name`` with the dmc preset's defaults (``time_limit`` counts env steps)."""
    return MjxTask(parse_mjx_task(name), action_repeat, time_limit)


def parse(task: str, rest: str) -> tuple[str]:
    """``mjx_<domain>_<task>`` -> ``(rest,)``; TaskError listing the MJX tasks otherwise."""
    parse_mjx_task(task)
    return (rest,)


def build(env_cfg) -> MjxTask:
    """The device task of an env config (its task, action repeat and time limit), wrapped in
    the partially observed and noisy variant options when one is set (``env.flicker``,
    ``env.hide``, ``env.show_keys``/``env.show_steps``, ``env.noise_dims``: see
    :mod:`vsgjax.envs.mjx.variants`) and the plain task otherwise. Raises ConfigError for an
    option the task cannot take (a key it does not observe, ...)."""
    from vsgjax.envs.mjx import variants

    task = make_mjx_task(env_cfg.task, env_cfg.action_repeat, env_cfg.time_limit)
    return variants.from_env_config(task, env_cfg)
