"""Public functional API for notebooks: ``init`` and a jitted ``world_model_step`` (the world
model trained alone), and, from the model layer, ``observe``, ``imagine`` and
``TrainedParams`` (:mod:`vsgjax.agents.dreamer.inference`,
:mod:`vsgjax.agents.dreamer.trained_params`). Training never imports this module.

Everything is a pure function of explicit params, state and PRNG keys; the config is a static
(hashable) argument. ``imagine`` accepts start states with any leading batch dimensions::

    state = init(config, key, obs_shape=(64, 64, 3), action_dim=2)   # or {"vector": (24,)}
    state, metrics, posts = world_model_step(config, state, batch, key)
    last = jax.tree.map(lambda x: x[:, -1], posts)           # [B] posterior states
    out = imagine(state.params, last, 15, config=config, key=key, action_dim=2)
    out["images"]                                             # [B, 15, 64, 64, 3] uint8

A trained run's params (:func:`vsgjax.load`) are a :class:`TrainedParams` pytree that carries
its config as static data, so from a notebook the call is simply::

    run = vsgjax.load("runs/bbs_basic-vsg-s0")
    out = imagine(run.params, state, H=15)    # config from the params, key PRNGKey(0), actor
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from vsgjax.agents.dreamer.inference import (
    DEFAULT_SEED,
    Policy,
    imagine,
    observe,
    world_model_for,
)
from vsgjax.agents.dreamer.optim import world_model_optimizer
from vsgjax.agents.dreamer.trained_params import TrainedParams
from vsgjax.agents.dreamer.world_model import WorldModel
from vsgjax.config import Config
from vsgjax.observations import ObsSpec

__all__ = ["DEFAULT_SEED", "Policy", "TrainState", "TrainedParams", "imagine", "init",
           "observe", "world_model_for", "world_model_step"]


class TrainState(NamedTuple):
    """World-model training state (a pytree)."""

    params: dict
    opt_state: optax.OptState
    step: jax.Array


def init(config: Config, key: jax.Array,
         obs_shape: ObsSpec | Mapping[str, Sequence[int]] | Sequence[int] = (64, 64, 3),
         action_dim: int = 2) -> TrainState:
    """Fresh world-model parameters and optimizer state (``action_dim`` 2 = BringBackShapes).

    ``obs_shape``: an image shape, a ``{key: shape}`` dict or an ObsSpec (see WorldModel).
    """
    return _init(WorldModel(config, obs_shape, action_dim), key)


@functools.partial(jax.jit, static_argnames="model")
def _init(model: WorldModel, key: jax.Array) -> TrainState:
    params = model.init(key)
    opt_state = world_model_optimizer(model.config).init(params)
    return TrainState(params, opt_state, jnp.zeros((), jnp.int32))


@functools.partial(jax.jit, static_argnames="config")
def world_model_step(config: Config, state: TrainState, batch: dict, key: jax.Array):
    """One world-model update on a [B, T] batch -> ``(state, metrics, posts)``.

    The batch holds the observation keys the params were built for (``image`` [B, T, 64, 64,
    C] uint8, vectors [B, T, D] float32) besides ``action``, ``reward``, ``is_first`` and
    ``is_terminal``. ``metrics`` adds the gradient's global norm (before clipping) to the loss
    metrics.
    """
    model = world_model_for(config, state.params, batch["action"].shape[-1])
    grad_fn = jax.value_and_grad(model.loss, has_aux=True)
    (_, (metrics, posts)), grads = grad_fn(state.params, batch, key)
    updates, opt_state = world_model_optimizer(config).update(grads, state.opt_state,
                                                                 state.params)
    params = optax.apply_updates(state.params, updates)
    metrics = dict(metrics, grad_norm=optax.tree.norm(grads))
    return TrainState(params, opt_state, state.step + 1), metrics, posts
