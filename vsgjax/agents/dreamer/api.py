"""Public functional API: ``init``, a jitted ``world_model_step`` (the world model alone),
``observe``, ``imagine``.

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

import dataclasses
import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from vsgjax.agents.dreamer.behaviour import Behaviour
from vsgjax.agents.dreamer.networks import float_to_image
from vsgjax.agents.dreamer.optim import world_model_optimizer
from vsgjax.agents.dreamer.world_model import WorldModel, obs_spec_of
from vsgjax.config import Config
from vsgjax.observations import ObsSpec


class TrainState(NamedTuple):
    """World-model training state (a pytree)."""

    params: dict
    opt_state: optax.OptState
    step: jax.Array


def world_model_for(config: Config, params: dict, action_dim: int = 0) -> WorldModel:
    """The :class:`WorldModel` matching ``params`` (its observation spec read from the
    decoders: :func:`vsgjax.agents.dreamer.world_model.obs_spec_of`)."""
    return WorldModel(config, obs_spec_of(params), action_dim)


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


@functools.partial(jax.jit, static_argnames="config")
def observe(config: Config, params: dict, batch: dict, key: jax.Array):
    """Posterior and prior states [B, T, ...] of a batch of sequences (no loss, no gradient)."""
    model = world_model_for(config, params, batch["action"].shape[-1])
    keys = jax.random.split(key, batch["action"].shape[0])
    return jax.vmap(model.observe, in_axes=(None, 0, 0))(params, batch, keys)


Policy = Callable[[jax.Array, jax.Array], jax.Array]

DEFAULT_SEED = 0  # imagine(key=None) uses jax.random.PRNGKey(DEFAULT_SEED): deterministic


@jax.tree_util.register_pytree_node_class
@dataclasses.dataclass(frozen=True, eq=False)
class TrainedParams:
    """A trained agent's parameters together with the static facts needed to use them.

    A pytree node: its children are the parameter dicts ``wm`` (world model), ``actor`` and
    ``critic`` (``None`` when absent, e.g. a world model trained alone); its aux data is the
    hashable ``(config, action_dim, discrete)``, which JAX treats as static. So a
    ``TrainedParams`` passes through ``jax.jit``, ``jax.tree.map`` or ``jax.device_put`` like
    the dicts it holds (the config becomes part of the compiled program's cache key, as a
    ``static_argnames`` argument would), and :func:`imagine` can read the config, the action
    size and the actor from it instead of asking for them. ``params["wm"]`` also works, as with
    the checkpoint's params dict.
    """

    wm: dict
    actor: dict | None
    critic: dict | None
    config: Config
    action_dim: int
    discrete: bool = False

    def tree_flatten(self):
        return (self.wm, self.actor, self.critic), (self.config, self.action_dim, self.discrete)

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(*children, *aux)

    def __getitem__(self, name: str):
        if name not in ("wm", "actor", "critic"):
            raise KeyError(name)
        return getattr(self, name)

    @property
    def behaviour(self) -> Behaviour:
        """The actor-critic networks these params belong to (static, hashable)."""
        return Behaviour.from_config(self.config, self.action_dim, self.discrete)


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
    if model.has_image and model.decodes:
        means = model.decode_frames(params, feats)
        out.update(images=float_to_image(means), image_means=means)
    if model.vector_keys:
        out["vectors"] = model.decode_vectors(params, feats)
    return out
