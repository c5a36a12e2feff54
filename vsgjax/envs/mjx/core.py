"""The pure-JAX task: physics loading, the control step, reset, action repeat and time limit.

A task is a frozen, hashable dataclass (:class:`MjxTask`) holding only plain values (its
:class:`TaskSpec` and the two counts), so it can be a static argument of ``jax.jit``; the
MuJoCo and MJX models are built once per spec and cached (:func:`physics`). All state lives
in :class:`MjxState`, a pytree, so ``jax.vmap(task.step)`` runs a batch of environments.

Stepping follows dm_control's ``control.Environment`` with ``legacy_step`` (its default): one
env step sets ``ctrl``, runs ``n_sub_steps`` physics steps (``mjx.step``: forward dynamics,
then integrate), then recomputes the position and velocity stages at the new state (MuJoCo's
``mj_step1``: ``fwd_position``, ``sensor_pos``, ``fwd_velocity``, ``sensor_vel``). So
positions, velocities and position/velocity sensors describe the new state, and
acceleration-stage sensors (touch) hold the values of the last substep's forward pass, as in
dm_control. Reward and observation are read from that data.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

Info = dict[str, jax.Array]  # per-episode task values outside the physics (reacher's target)


class MjxState(NamedTuple):
    """One environment's state after reset or an agent step (a pytree; batch it with vmap).

    ``reward`` is the sum over the action repeats of this agent step (0 after reset);
    ``step`` counts env steps (physics control steps) since reset; ``is_last`` is set when
    ``step`` reaches the time limit (a truncation: ``is_terminal`` is always False, as no
    suite task ends early). ``key`` is the episode's key, for a caller's next reset.
    """

    data: mjx.Data
    obs: dict[str, jax.Array]
    reward: jax.Array
    is_first: jax.Array
    is_last: jax.Array
    is_terminal: jax.Array
    step: jax.Array
    key: jax.Array
    info: Info


@dataclasses.dataclass(frozen=True, eq=False)
class Physics:
    """The compiled MuJoCo model, its MJX copy and the constants stepping needs."""

    mj: mujoco.MjModel
    mx: mjx.Model
    n_sub_steps: int
    ctrl_low: np.ndarray
    ctrl_high: np.ndarray


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """One suite task: how to build its model and its dm_control task logic in JAX.

    ``load`` returns ``(xml, assets)`` (dm_control's ``get_model_and_assets``); ``edit`` makes
    the task's own changes to the compiled model (dm_control's ``initialize_episode`` edits
    that are the same every episode, such as finger spin's hinge damping). ``init(key, phys,
    data) -> (data, info)`` randomises the initial state; ``observe(phys, data, info)`` returns
    the observation dict (keys in ``obs_keys`` order) and ``reward(phys, data, info)`` a scalar.
    ``control_timestep`` is dm_control's (None: the model's timestep).
    """

    domain: str
    task: str
    load: Callable[[], tuple[str, dict]]
    init: Callable[..., tuple[mjx.Data, Info]]
    observe: Callable[..., dict[str, jax.Array]]
    reward: Callable[..., jax.Array]
    obs_keys: tuple[str, ...]
    control_timestep: float | None = None
    edit: Callable[[mujoco.MjModel], None] | None = None

    @property
    def name(self) -> str:
        return f"mjx_{self.domain}_{self.task}"


# MJX rejects models with the energy flag (cartpole, pendulum). Energy is a diagnostic that no
# force, observation or reward depends on, so it is switched off.
_UNSUPPORTED_BUT_HARMLESS_ENABLE = mujoco.mjtEnableBit.mjENBL_ENERGY


def load_model(spec: TaskSpec) -> mujoco.MjModel:
    """dm_control's XML compiled by MuJoCo, with the energy flag cleared and the task's edits."""
    xml, assets = spec.load()
    model = mujoco.MjModel.from_xml_string(xml, assets)
    model.opt.enableflags &= ~int(_UNSUPPORTED_BUT_HARMLESS_ENABLE)
    if spec.edit is not None:
        spec.edit(model)
    return model


@functools.cache
def physics(spec: TaskSpec) -> Physics:
    """Build (once per spec) the models; raises naming the feature MJX does not support."""
    model = load_model(spec)
    try:
        with jax.ensure_compile_time_eval():  # concrete arrays even when first built in a trace
            mx = mjx.put_model(model, impl="jax")
    except NotImplementedError as error:
        raise NotImplementedError(f"{spec.name}: MJX does not support {error} used by "
                                  f"dm_control's {spec.domain}.xml") from error
    timestep = float(model.opt.timestep)
    control = spec.control_timestep or timestep
    n_sub_steps = int(round(control / timestep))
    if abs(n_sub_steps * timestep - control) > 1e-8:
        raise ValueError(f"{spec.name}: control timestep {control} is not a multiple of the "
                         f"physics timestep {timestep}")
    low, high = model.actuator_ctrlrange.T.astype(np.float32)
    return Physics(model, mx, n_sub_steps, low, high)


def step1(m: mjx.Model, d: mjx.Data) -> mjx.Data:
    """MuJoCo's ``mj_step1``: position and velocity stages (and their sensors) at the state."""
    d = mjx.fwd_position(m, d)
    d = mjx.sensor_pos(m, d)
    d = mjx.fwd_velocity(m, d)
    return mjx.sensor_vel(m, d)


def control_step(phys: Physics, d: mjx.Data, ctrl: jax.Array) -> mjx.Data:
    """One env step: ``n_sub_steps`` physics steps under ``ctrl``, then ``step1``."""
    d = d.replace(ctrl=ctrl)
    d = jax.lax.fori_loop(0, phys.n_sub_steps, lambda _, x: mjx.step(phys.mx, x), d)
    return step1(phys.mx, d)


def after_reset(phys: Physics, d: mjx.Data) -> mjx.Data:
    """dm_control's ``after_reset``: ``mj_forward`` with zero control (actuation disabled)."""
    return mjx.forward(phys.mx, d.replace(ctrl=jnp.zeros_like(d.ctrl)))


@dataclasses.dataclass(frozen=True)
class MjxTask:
    """A suite task in JAX with action repeat and a time limit (``time_limit`` in env steps).

    ``reset(key) -> MjxState``; ``step(state, action) -> MjxState`` with ``action`` in
    ``[-1, 1]^action_dim``, mapped affinely onto the actuators' ``ctrlrange``. Stepping a
    state whose ``is_last`` is set keeps simulating; reset it instead.
    """

    spec: TaskSpec
    action_repeat: int = 2
    time_limit: int = 1000

    def __post_init__(self):
        if self.action_repeat < 1 or self.time_limit < 1:
            raise ValueError(f"action_repeat and time_limit must be >= 1, got "
                             f"{self.action_repeat}, {self.time_limit}")

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def physics(self) -> Physics:
        return physics(self.spec)

    @property
    def action_dim(self) -> int:
        return int(self.physics.mj.nu)

    @property
    def discrete(self) -> bool:
        return False

    @property
    def episode_steps(self) -> int:
        """Agent steps per episode: every episode is truncated at the time limit (the last
        agent step may repeat the action fewer times)."""
        return math.ceil(self.time_limit / self.action_repeat)

    @property
    def obs_keys(self) -> tuple[str, ...]:
        return self.spec.obs_keys

    def observation_spec(self) -> dict[str, tuple[tuple[int, ...], Any]]:
        """``{name: (shape, dtype)}`` in dm_control's key order (room for image keys later)."""
        shapes = jax.eval_shape(self.reset, jax.random.PRNGKey(0)).obs
        return {k: (tuple(shapes[k].shape), shapes[k].dtype) for k in self.obs_keys}

    def flat_obs(self, obs: dict[str, jax.Array]) -> jax.Array:
        """The observation as one vector in dm_control's key order (``flatten_observation``).

        Works on batched observations too (leading axes are kept)."""
        return jnp.concatenate([obs[k] for k in self.obs_keys], axis=-1)

    def reset(self, key: jax.Array) -> MjxState:
        """A new episode, randomised as dm_control's ``initialize_episode``."""
        key, init_key = jax.random.split(key)
        phys = self.physics
        data, info = self.spec.init(init_key, phys, mjx.make_data(phys.mx, impl="jax"))
        return self._first(phys, after_reset(phys, data), info, key)

    def reset_to(self, key: jax.Array, qpos, qvel, info: Info | None = None) -> MjxState:
        """A new episode from a given physics state (and task info, e.g. reacher's target)."""
        phys = self.physics
        data = mjx.make_data(phys.mx, impl="jax")
        data = data.replace(qpos=jnp.asarray(qpos, data.qpos.dtype),
                            qvel=jnp.asarray(qvel, data.qvel.dtype))
        info = info if info is not None else self.spec.init(key, phys, data)[1]
        return self._first(phys, after_reset(phys, data), info, key)

    def _first(self, phys: Physics, data: mjx.Data, info: Info, key: jax.Array) -> MjxState:
        false = jnp.zeros((), bool)
        return MjxState(data, self._observe(phys, data, info), jnp.zeros((), jnp.float32),
                        jnp.ones((), bool), false, false, jnp.zeros((), jnp.int32), key, info)

    def _observe(self, phys: Physics, data: mjx.Data, info: Info) -> dict[str, jax.Array]:
        obs = self.spec.observe(phys, data, info)
        return {k: obs[k].astype(jnp.float32) for k in self.obs_keys}

    def step(self, state: MjxState, action: jax.Array) -> MjxState:
        """One agent step: ``action_repeat`` env steps (fewer if the time limit comes first)."""
        phys = self.physics
        action = jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        ctrl = phys.ctrl_low + (action + 1.0) / 2.0 * (phys.ctrl_high - phys.ctrl_low)

        def repeat(carry, _):
            data, reward, count = carry
            active = count < self.time_limit
            new = control_step(phys, data, ctrl)
            data = jax.tree.map(lambda a, b: jnp.where(active, a, b), new, data)
            reward += jnp.where(active, self.spec.reward(phys, new, state.info), 0.0).astype(
                jnp.float32)
            return (data, reward, count + active.astype(jnp.int32)), None

        init = (state.data, jnp.zeros((), jnp.float32), state.step)
        (data, reward, count), _ = jax.lax.scan(repeat, init, None, self.action_repeat)
        false = jnp.zeros((), bool)
        return MjxState(data, self._observe(phys, data, state.info),
                        reward.astype(jnp.float32), false, count >= self.time_limit, false,
                        count, state.key, state.info)
