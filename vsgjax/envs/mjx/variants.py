"""Partially observed and noisy variants of any MJX task, in pure JAX.

:class:`VariantTask` wraps an :class:`~vsgjax.envs.mjx.core.MjxTask` and changes only what the
agent observes; the physics, rewards, action repeat and time limit are the wrapped task's, and
its state (:class:`VariantState`) carries the wrapped task's state unchanged, so a variant's
episode is the plain task's episode from the same reset key, observed differently. Options
(``env.*`` keys; :func:`from_env_config` builds the wrapper from them):

* ``hide`` (``env.hide``): these observation keys are zero at every step.
* ``show_keys`` for ``show_steps`` = k (``env.show_keys``, ``env.show_steps``): these keys are
  the task's own at agent steps t = 0, ..., k - 1 of an episode, where t = 0 is the reset
  observation and t = i the observation after the i-th action, and zero from t = k on. The
  suite's one per-episode goal that nothing else reveals is reacher's target
  (``mjx_reacher_easy``, ``env.show_keys=to_target``: the target geom takes no part in the
  dynamics; ``position`` and ``velocity`` are the arm's). Showing a task's ``position`` once
  (``env.show_steps=1``) leaves its velocities, from which the positions must be integrated
  for the whole episode. Hiding a key (``velocity``) asks for a memory of a few steps only (a
  difference of positions), not of the whole episode.
* ``noise_dims`` = K with ``noise_scale`` = s (``env.noise_dims``, ``env.noise_scale``): K
  extra dims, the observation key ``noise`` appended after the task's keys, that follow
  independent Gaussian random walks (Brownian motion sampled once per agent step, as
  BringBackShapes' distractors move): n_0 = 0 at reset, n_{t+1} = n_t + s * e_t with e_t ~
  N(0, I_K), so n_t ~ N(0, t s^2 I_K). The increments come from the state's own key stream:
  they do not depend on the actions, the rewards or the physics.
* ``flicker`` = p (``env.flicker``): at every agent step, and at reset too, the whole
  observation (the noise dims included) is replaced by zeros with probability p,
  independently per env and step (DRQN's flickering Atari). The reset observation flickers
  like any other, so every recorded observation of an episode is blanked i.i.d. with
  probability p and no step is special to the agent (the first step is marked by
  ``is_first``, not by being visible); a shown-once key can therefore be lost to flicker,
  which ``show_steps`` > 1 makes less likely (probability p^k).

Order at each observation: the task's observation -> hidden keys zeroed -> shown-once keys
zeroed from t = k -> noise dims appended -> flicker. The noise walk keeps moving under flicker
(flicker hides it, it does not stop it).

Randomness: the variant's key stream starts at ``fold_in(reset_key, VARIANT_STREAM)``, apart
from the keys the wrapped task draws from ``reset_key``; each observation splits it once
(flicker), each step once more (the noise increment), whatever options are on, so an episode
is a deterministic function of its reset key and the same reset key flickers the same steps
with or without noise. The wrapped task's ``state.key`` (the next episode's reset key) is
the state's ``key``, as the vector env and the device loop expect.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from vsgjax.config.schema import ConfigError
from vsgjax.envs.mjx.core import MjxState, MjxTask

NOISE_KEY = "noise"  # the observation key of the noise dims (after the task's keys)
VARIANT_STREAM = 36  # fold_in(reset key, VARIANT_STREAM): the variant's own key stream


class VariantState(NamedTuple):
    """A variant's state: the wrapped task's state and what the agent sees of it (a pytree).

    ``plain``: the wrapped task's :class:`MjxState`, its observation unchanged; ``obs``: the
    variant's observation (``VariantTask.obs_keys``); ``variant_key``: the variant's key
    stream; ``t``: agent steps since reset (0 at reset); ``noise``: the random walk n_t [K]
    (before flicker); ``flickered``: whether this observation was blanked. ``reward``,
    ``is_first``, ``is_last``, ``is_terminal``, ``step``, ``key``, ``data`` and ``info`` are
    the wrapped state's.
    """

    plain: MjxState
    obs: dict[str, jax.Array]
    variant_key: jax.Array
    t: jax.Array
    noise: jax.Array
    flickered: jax.Array

    @property
    def reward(self) -> jax.Array:
        return self.plain.reward

    @property
    def is_first(self) -> jax.Array:
        return self.plain.is_first

    @property
    def is_last(self) -> jax.Array:
        return self.plain.is_last

    @property
    def is_terminal(self) -> jax.Array:
        return self.plain.is_terminal

    @property
    def step(self) -> jax.Array:
        return self.plain.step

    @property
    def key(self) -> jax.Array:
        return self.plain.key

    @property
    def data(self):
        return self.plain.data

    @property
    def info(self):
        return self.plain.info


def parse_keys(text: str, option: str, valid: tuple[str, ...]) -> tuple[str, ...]:
    """``"a, b,c"`` -> ``("a", "b", "c")`` (repeats once; ``""``: none); ConfigError naming
    ``env.<option>`` and the ``valid`` keys for an empty entry (``"a,"``, ``"a,,b"``)."""
    if not text.strip():
        return ()
    parts = [part.strip() for part in text.split(",")]
    if not all(parts):
        raise ConfigError(f"env.{option}={text!r} has an empty key; valid: comma-separated "
                          f"keys of {', '.join(valid)}, e.g. env.{option}={valid[0]}")
    return tuple(dict.fromkeys(parts))


@dataclasses.dataclass(frozen=True)
class VariantTask:
    """An MJX task observed through the variant options (see the module doc); frozen and
    hashable, so it is a static argument of ``jax.jit`` as the plain task is.

    Raises ConfigError naming the ``env.*`` key, the value and what is valid.
    """

    task: MjxTask
    flicker: float = 0.0
    hide: tuple[str, ...] = ()
    show_keys: tuple[str, ...] = ()
    show_steps: int = 0
    noise_dims: int = 0
    noise_scale: float = 0.1

    def __post_init__(self):
        keys = self.task.obs_keys
        valid = ", ".join(keys)
        if not (math.isfinite(self.flicker) and 0 <= self.flicker < 1):
            raise ConfigError(f"env.flicker={self.flicker!r}; valid: a probability in [0, 1)")
        for option, chosen in (("hide", self.hide), ("show_keys", self.show_keys)):
            unknown = [key for key in chosen if key not in keys]
            if unknown:
                raise ConfigError(f"env.{option}={','.join(chosen)!r}: {self.task.name} has no "
                                  f"observation key {unknown[0]!r}; valid: comma-separated "
                                  f"keys of {valid}")
        both = [key for key in self.hide if key in self.show_keys]
        if both:
            raise ConfigError(f"observation key {both[0]!r} is in env.hide and env.show_keys; "
                              "valid: a key in one of them")
        if self.show_keys and self.show_steps < 1:
            raise ConfigError(f"env.show_steps={self.show_steps} with env.show_keys="
                              f"{','.join(self.show_keys)!r}; valid: >= 1 (agent steps shown, "
                              "the reset observation is step 0)")
        if self.show_steps and not self.show_keys:
            raise ConfigError(f"env.show_steps={self.show_steps} without env.show_keys; valid: "
                              f"env.show_steps=0, or env.show_keys from {valid}")
        if self.noise_dims < 0:
            raise ConfigError(f"env.noise_dims={self.noise_dims}; valid: >= 0")
        if not (math.isfinite(self.noise_scale) and self.noise_scale >= 0):
            raise ConfigError(f"env.noise_scale={self.noise_scale!r}; valid: >= 0")
        if self.noise_dims and NOISE_KEY in keys:
            raise ConfigError(f"{self.task.name} has an observation key {NOISE_KEY!r} of its "
                              "own; env.noise_dims needs the name: valid: env.noise_dims=0")

    # --- what the loops read of a task (as MjxTask) ------------------------------------------

    @property
    def name(self) -> str:
        """The wrapped task's name (the variant is in the run's ``env.*`` config)."""
        return self.task.name

    @property
    def spec(self):
        return self.task.spec

    @property
    def physics(self):
        return self.task.physics

    @property
    def action_dim(self) -> int:
        return self.task.action_dim

    @property
    def action_repeat(self) -> int:
        return self.task.action_repeat

    @property
    def time_limit(self) -> int:
        return self.task.time_limit

    @property
    def discrete(self) -> bool:
        return False

    @property
    def episode_steps(self) -> int:
        return self.task.episode_steps

    @property
    def obs_keys(self) -> tuple[str, ...]:
        """The task's keys, then ``noise`` when ``noise_dims`` > 0."""
        return self.task.obs_keys + ((NOISE_KEY,) if self.noise_dims else ())

    def observation_spec(self) -> dict[str, tuple[tuple[int, ...], Any]]:
        """``{name: (shape, dtype)}`` in :attr:`obs_keys` order (the noise dims included)."""
        shapes = jax.eval_shape(self.reset, jax.random.PRNGKey(0)).obs
        return {k: (tuple(shapes[k].shape), shapes[k].dtype) for k in self.obs_keys}

    def flat_obs(self, obs: dict[str, jax.Array]) -> jax.Array:
        """The observation as one vector in :attr:`obs_keys` order (batched too)."""
        return jnp.concatenate([obs[k] for k in self.obs_keys], axis=-1)

    # --- stepping ------------------------------------------------------------------------------

    def reset(self, key: jax.Array) -> VariantState:
        """The wrapped task's ``reset(key)``, observed at t = 0 with n_0 = 0."""
        return self._start(self.task.reset(key), key)

    def reset_to(self, key: jax.Array, qpos, qvel, info=None) -> VariantState:
        """The wrapped task's ``reset_to``, with the variant stream of ``reset(key)``."""
        return self._start(self.task.reset_to(key, qpos, qvel, info), key)

    def step(self, state: VariantState, action: jax.Array) -> VariantState:
        """The wrapped task's step; the noise walk moves on, then the new observation."""
        plain = self.task.step(state.plain, action)
        variant_key, noise_key = jax.random.split(state.variant_key)
        increment = jax.random.normal(noise_key, (self.noise_dims,), jnp.float32)
        noise = state.noise + jnp.float32(self.noise_scale) * increment
        return self._observe(plain, variant_key, state.t + 1, noise)

    def _start(self, plain: MjxState, key: jax.Array) -> VariantState:
        variant_key = jax.random.fold_in(key, VARIANT_STREAM)
        return self._observe(plain, variant_key, jnp.zeros((), jnp.int32),
                             jnp.zeros((self.noise_dims,), jnp.float32))

    def _observe(self, plain: MjxState, variant_key: jax.Array, t: jax.Array,
                 noise: jax.Array) -> VariantState:
        variant_key, flicker_key = jax.random.split(variant_key)
        obs = dict(plain.obs)
        for key in self.hide:
            obs[key] = jnp.zeros_like(obs[key])
        shown = t < self.show_steps
        for key in self.show_keys:
            obs[key] = jnp.where(shown, obs[key], jnp.zeros_like(obs[key]))
        if self.noise_dims:
            obs[NOISE_KEY] = noise
        flickered = jnp.zeros((), bool)
        if self.flicker > 0:
            flickered = jax.random.uniform(flicker_key) < self.flicker
            obs = {k: jnp.where(flickered, jnp.zeros_like(v), v) for k, v in obs.items()}
        return VariantState(plain, {k: obs[k] for k in self.obs_keys}, variant_key, t, noise,
                            flickered)


def options(env_cfg, keys: tuple[str, ...]) -> dict:
    """The variant options of an ``EnvConfig`` as :class:`VariantTask` arguments (``keys``:
    the task's observation keys, named when ``env.hide`` or ``env.show_keys`` is malformed)."""
    return {"flicker": env_cfg.flicker, "hide": parse_keys(env_cfg.hide, "hide", keys),
            "show_keys": parse_keys(env_cfg.show_keys, "show_keys", keys),
            "show_steps": env_cfg.show_steps,
            "noise_dims": env_cfg.noise_dims, "noise_scale": env_cfg.noise_scale}


def from_env_config(task: MjxTask, env_cfg) -> MjxTask | VariantTask:
    """``task`` wrapped in the config's variant options, or ``task`` itself when none is set
    (``env.noise_scale`` alone changes nothing: it scales noise dims that are not there), so
    a run without variants steps exactly the plain task. Raises ConfigError for a bad option
    (a key the task does not observe, ...)."""
    chosen = options(env_cfg, task.obs_keys)
    if not (chosen["flicker"] or chosen["hide"] or chosen["show_keys"] or chosen["show_steps"]
            or chosen["noise_dims"]):
        return task
    return VariantTask(task, **chosen)
