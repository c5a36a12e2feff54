"""Filtering and imagination with a world model's parameters: ``observe`` (posterior and
prior states of recorded sequences) and ``imagine`` (the prior rolled forward and decoded).

Pure functions of explicit params, start states and PRNG keys, with the config a static
(hashable) argument; the model layer under the notebook API (:mod:`vsgjax.agents.dreamer.api`
re-exports them) and what open-loop evaluation and gate statistics are built on.
``imagine`` accepts start states with any leading batch dimensions, and the
:class:`~vsgjax.agents.dreamer.trained_params.TrainedParams` of a trained run in place of the
params and config::

    posts, _ = observe(config, params, batch, key)            # [B, T] states
    last = jax.tree.map(lambda x: x[:, -1], posts)           # [B] posterior states
    out = imagine(params, last, 15, config=config, key=key, action_dim=2)
    out["images"]                                             # [B, 15, 64, 64, 3] uint8
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer.behaviour import Behaviour
from vsgjax.agents.dreamer.trained_params import TrainedParams
from vsgjax.agents.dreamer.world_model import WorldModel, obs_spec_of
from vsgjax.config import Config


def world_model_for(config: Config, params: dict, action_dim: int = 0) -> WorldModel:
    """The :class:`WorldModel` matching ``params`` (its observation spec read from the
    decoders: :func:`vsgjax.agents.dreamer.world_model.obs_spec_of`)."""
    return WorldModel(config, obs_spec_of(params), action_dim)


@functools.partial(jax.jit, static_argnames="config")
def observe(config: Config, params: dict, batch: dict, key: jax.Array):
    """Posterior and prior states [B, T, ...] of a batch of sequences (no loss, no gradient)."""
    model = world_model_for(config, params, batch["action"].shape[-1])
    keys = jax.random.split(key, batch["action"].shape[0])
    return jax.vmap(model.observe, in_axes=(None, 0, 0))(params, batch, keys)


Policy = Callable[[jax.Array, jax.Array], jax.Array]

DEFAULT_SEED = 0  # imagine(key=None) uses jax.random.PRNGKey(DEFAULT_SEED): deterministic


def imagine(params: dict | TrainedParams, state: Any, H: int = 15, *,
            config: Config | None = None, key: jax.Array | None = None,
            actions: jax.Array | None = None, policy: Policy | None = None,
            action_dim: int | None = None) -> dict:
    """Roll the prior forward ``H`` steps from (possibly batched) start states and decode.

    ``params`` is the world model's params dict (then ``config`` is required), or the
    :class:`TrainedParams` of a trained run (:func:`vsgjax.load`), which carries its config.
    ``key`` defaults to ``jax.random.PRNGKey(DEFAULT_SEED)`` (0), so a call without a key is
    deterministic; pass keys to draw different samples.

    The actions come from, in this order of precedence: ``actions`` ``[..., H, A]`` (open
    loop), ``policy(feat, key) -> action`` (closed loop), zeros of size ``action_dim`` when it
    is given, and otherwise, for ``TrainedParams``, samples of the trained actor (closed loop,
    as behaviour learning imagines), or zeros when the params carry no actor. A plain params
    dict needs one of ``actions``, ``policy`` or ``action_dim``.
    Returns a dict of arrays with leading dims ``[..., H]``: the imagined ``states`` (the
    state after each action; the start state is not repeated), ``actions``, ``feats``,
    ``rewards``, ``discounts``, and the decoded observations: ``images`` (uint8) and
    ``image_means`` (float, [-0.5, 0.5]) when the model has an image and a decoder (not the
    prototype models, DreamerPro's), ``vectors`` (``{key: mean [..., H, D]}``) when it has
    vector keys.
    Pure and jit-friendly: ``jax.jit(lambda p, s: imagine(p, s, H=15))(run.params, state)``.
    """
    actor = actor_params = None
    if isinstance(params, TrainedParams):
        if config is not None and config != params.config:
            raise ValueError("config= differs from the config the TrainedParams carry; "
                             "leave config out")
        config, trained, params = params.config, params, params.wm
        if actions is None and policy is None and action_dim is None:
            if trained.actor is not None:
                actor, actor_params = trained.behaviour, trained.actor
            else:
                action_dim = trained.action_dim
    else:
        if config is None:
            raise TypeError("imagine needs config= with a plain params dict (the TrainedParams "
                            "of vsgjax.load carry their config)")
        if actions is None and policy is None and action_dim is None:
            raise ValueError("imagine needs actions, a policy, or action_dim (for zero actions)")
    if key is None:
        key = jax.random.PRNGKey(DEFAULT_SEED)
    model = world_model_for(config, params)
    batch_shape = _batch_shape(model, state)
    start = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[len(batch_shape):]), state)
    count = jax.tree.leaves(start)[0].shape[0]
    if actions is None and policy is None and actor is None:
        actions = jnp.zeros(batch_shape + (H, action_dim), jnp.float32)
    if actions is not None:
        actions = jnp.asarray(actions, jnp.float32)
        if actions.shape[len(batch_shape)] != H:
            raise ValueError(f"actions have horizon {actions.shape[len(batch_shape)]}, H is {H}")
        actions = actions.reshape((count, H, actions.shape[-1]))
    out = _imagine_flat(model, params, start, H, key, actions, policy, actor, actor_params)
    return jax.tree.map(lambda x: x.reshape(batch_shape + x.shape[1:]), out)


def _batch_shape(model: WorldModel, state: Any) -> tuple[int, ...]:
    """Leading dims of ``state`` beyond those of one unbatched dynamics state."""
    leaf, single = jax.tree.leaves(state)[0], jax.tree.leaves(model.dynamics.initial())[0]
    return tuple(leaf.shape[: leaf.ndim - single.ndim])


@functools.partial(jax.jit, static_argnames=("model", "H", "policy", "actor"))
def _imagine_flat(model: WorldModel, params: dict, start: Any, H: int, key: jax.Array,
                  actions: jax.Array | None, policy: Policy | None,
                  actor: Behaviour | None = None, actor_params: dict | None = None) -> dict:
    dyn = model.dynamics
    if actor is not None:  # the actor's parameters are traced arguments, its networks static
        def policy(feat, policy_key):
            return actor.act(actor_params, feat, policy_key)
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
    out = {
        "states": states, "actions": actions, "feats": feats,
        "rewards": model.reward_mean(params, feats),
        "discounts": model.discount(params, feats),
    }
    out.update(model.representation.imagined_observations(params, feats))
    return out
