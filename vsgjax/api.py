"""Public functional API: ``init``, a jitted world-model ``train_step``, ``observe``, ``imagine``.

Everything is a pure function of explicit params, state and PRNG keys; the config is a static
(hashable) argument. ``imagine`` accepts start states with any leading batch dimensions::

    state = init(config, key, obs_shape=(64, 64, 3), action_dim=2)
    state, metrics, posts = train_step(config, state, batch, key)
    last = jax.tree.map(lambda x: x[:, -1], posts)           # [B] posterior states
    out = imagine(state.params, last, 15, config=config, key=key, action_dim=2)
    out["images"]                                             # [B, 15, 64, 64, 3] uint8
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from vsgjax.config import Config
from vsgjax.networks import DECODER_KERNELS, float_to_image
from vsgjax.optim import world_model_optimizer
from vsgjax.world_model import WorldModel


class TrainState(NamedTuple):
    """World-model training state (a pytree)."""

    params: dict
    opt_state: optax.OptState
    step: jax.Array


def world_model_for(config: Config, params: dict, action_dim: int = 0) -> WorldModel:
    """The :class:`WorldModel` matching ``params`` (image channels read from the decoder)."""
    last = f"ConvTranspose2_{len(DECODER_KERNELS) - 1}"
    channels = params["decoder"][last]["bias"].shape[-1]
    return WorldModel(config, (64, 64, channels), action_dim)


def init(config: Config, key: jax.Array, obs_shape: tuple[int, int, int] = (64, 64, 3),
         action_dim: int = 2) -> TrainState:
    """Fresh world-model parameters and optimizer state (``action_dim`` 2 = BringBackShapes)."""
    return _init(WorldModel(config, tuple(obs_shape), action_dim), key)


@functools.partial(jax.jit, static_argnames="model")
def _init(model: WorldModel, key: jax.Array) -> TrainState:
    params = model.init(key)
    opt_state = world_model_optimizer(model.config).init(params)
    return TrainState(params, opt_state, jnp.zeros((), jnp.int32))


@functools.partial(jax.jit, static_argnames="config")
def train_step(config: Config, state: TrainState, batch: dict, key: jax.Array):
    """One world-model update on a [B, T] batch -> ``(state, metrics, posts)``.

    ``metrics`` adds the gradient's global norm (before clipping) to the loss metrics.
    """
    model = WorldModel(config, batch["image"].shape[2:], batch["action"].shape[-1])
    grad_fn = jax.value_and_grad(model.loss, has_aux=True)
    (_, (metrics, posts)), grads = grad_fn(state.params, batch, key)
    updates, opt_state = world_model_optimizer(config).update(grads, state.opt_state,
                                                                 state.params)
    params = optax.apply_updates(state.params, updates)
    metrics = dict(metrics, grad_norm=optax.tree.norm(grads))
    return TrainState(params, opt_state, state.step + 1), metrics, posts


@functools.partial(jax.jit, static_argnames="config")
def observe(config: Config, params: dict, batch: dict, key: jax.Array):
    """Posterior and prior states [B, T, ...] of a batch of sequences (no loss, no gradient)."""
    model = world_model_for(config, params, batch["action"].shape[-1])
    keys = jax.random.split(key, batch["image"].shape[0])
    return jax.vmap(model.observe, in_axes=(None, 0, 0))(params, batch, keys)


Policy = Callable[[jax.Array, jax.Array], jax.Array]


def imagine(params: dict, state: Any, H: int = 15, *, config: Config, key: jax.Array,
            actions: jax.Array | None = None, policy: Policy | None = None,
            action_dim: int | None = None) -> dict:
    """Roll the prior forward ``H`` steps from (possibly batched) start states and decode.

    The actions come from, in this order of precedence: ``actions`` ``[..., H, A]`` (open
    loop), ``policy(feat, key) -> action`` (closed loop), or zeros of size ``action_dim``.
    Returns a dict of arrays with leading dims ``[..., H]``: the imagined ``states`` (the
    state after each action; the start state is not repeated), ``actions``, ``feats``,
    ``images`` (uint8), ``image_means`` (float, [-0.5, 0.5]), ``rewards`` and ``discounts``.
    """
    if actions is None and policy is None and action_dim is None:
        raise ValueError("imagine needs actions, a policy, or action_dim (for zero actions)")
    model = world_model_for(config, params)
    batch_shape = _batch_shape(model, state)
    start = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[len(batch_shape):]), state)
    count = jax.tree.leaves(start)[0].shape[0]
    if actions is None and policy is None:
        actions = jnp.zeros(batch_shape + (H, action_dim), jnp.float32)
    if actions is not None:
        if actions.shape[len(batch_shape)] != H:
            raise ValueError(f"actions have horizon {actions.shape[len(batch_shape)]}, H is {H}")
        actions = actions.reshape((count, H, actions.shape[-1]))
    out = _imagine_flat(model, params, start, H, key, actions, policy)
    return jax.tree.map(lambda x: x.reshape(batch_shape + x.shape[1:]), out)


def _batch_shape(model: WorldModel, state: Any) -> tuple[int, ...]:
    """Leading dims of ``state`` beyond those of one unbatched dynamics state."""
    leaf, single = jax.tree.leaves(state)[0], jax.tree.leaves(model.dynamics.initial())[0]
    return tuple(leaf.shape[: leaf.ndim - single.ndim])


@functools.partial(jax.jit, static_argnames=("model", "H", "policy"))
def _imagine_flat(model: WorldModel, params: dict, start: Any, H: int, key: jax.Array,
                  actions: jax.Array | None, policy: Policy | None) -> dict:
    dyn = model.dynamics
    keys = jax.random.split(key, jax.tree.leaves(start)[0].shape[0])
    if actions is not None:
        states = jax.vmap(dyn.rollout, in_axes=(None, 0, 0, 0))(
            params["dynamics"], start, actions, keys)
    else:
        states, actions = jax.vmap(dyn.imagine, in_axes=(None, None, 0, None, 0))(
            params["dynamics"], policy, start, H, keys)
        states = jax.tree.map(lambda x: x[:, 1:], states)
        actions = actions[:, :-1]
    feats = jax.vmap(jax.vmap(dyn.feat))(states)
    means = model.decode_frames(params, feats)
    return {
        "states": states, "actions": actions, "feats": feats,
        "images": float_to_image(means), "image_means": means,
        "rewards": model.reward_mean(params, feats),
        "discounts": model.discount(params, feats),
    }
