"""The latent-dynamics interface shared by RSSM, SSM and SVSG, and their state pytrees (which
model takes which dynamics: its registry entry's ``dynamics`` option,
:mod:`vsgjax.registry.agents`).

Every function is PER EXAMPLE (no batch axis); batch with ``jax.vmap`` and per-example keys.
A model is a frozen (hashable, jit-static) dataclass holding its :class:`ModelConfig`, its
model's name and its precision::

    params = dyn.init(key, embed_dim, action_dim)
    prior = dyn.img_step(params, prev_state, prev_action, key)
    post, prior = dyn.obs_step(params, prev_state, prev_action, embed, key)
    posts, priors = dyn.observe(params, embeds[T, E], actions[T, A], is_first[T], key)
    states, actions = dyn.imagine(params, policy, start, horizon, key)   # H + 1 of each
    states = dyn.rollout(params, start, actions[H, A], key)              # H states

Subclasses implement ``init``, ``initial``, ``img_step``, ``feat``/``feat_dim`` and the
posterior step on a pre-projected embedding (``project_embed`` + ``_obs_step_projected``):
the posterior's first dense layer over ``[·, e]`` is split into a part on ``e`` and a part on
the rest, so :meth:`observe` projects all ``T`` embeddings in one matmul outside the scan.
Every dense layer's matmul runs in :attr:`Dynamics.dtype` (``precision``,
:mod:`vsgjax.agents.precision`); states, distributions and gates are float32.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer.cells import (
    BERNOULLI_GATE,
    GATE_MODES,
    GateCell,
    dense,
    dense_init,
    open_probability,
)
from vsgjax.agents.dreamer.distributions import Latent, LatentSpace
from vsgjax.agents.dreamer.settings import ModelConfig
from vsgjax.agents.precision import compute_dtype
from vsgjax.registry.agents import gated_models


class RSSMState(NamedTuple):
    """DreamerV1/V2 state: ``deter`` ``[deter]``, ``stoch`` ``[stoch]`` or ``[stoch, classes]``."""

    deter: jax.Array
    stoch: jax.Array
    dist: Latent


class GatedRSSMState(NamedTuple):
    """VSG state: RSSM fields plus the cell's gate sample and logit, both ``[deter]``.

    ``gate`` is straight-through (exactly 0/1 forward); ``σ(gate_logit)`` is its probability.
    """

    deter: jax.Array
    stoch: jax.Array
    dist: Latent
    gate: jax.Array
    gate_logit: jax.Array


class SVSGState(NamedTuple):
    """SVSG state: gated Gaussian ``stoch`` ``[stoch]``; ``dist`` is that of the candidate ``ẑ``."""

    stoch: jax.Array
    dist: Latent
    gate: jax.Array
    gate_logit: jax.Array


class SSMState(NamedTuple):
    """Purely stochastic PlaNet SSM state."""

    stoch: jax.Array
    dist: Latent


State = RSSMState | GatedRSSMState | SVSGState | SSMState
Policy = Callable[[jax.Array, jax.Array], jax.Array]  # (feat [F], key) -> action [A]


def _append(seq, last):
    """Append one step (pytree) to a stacked sequence (pytree with leading time axis)."""
    return jax.tree.map(lambda xs, x: jnp.concatenate([xs, x[None]], 0), seq, last)


@dataclass(frozen=True)
class Dynamics(abc.ABC):
    """Base class: the scans, KL, entropy and gate accessors common to every model.

    ``gate``: the sparse cell's gate of the gated models (the world-model objective's:
    :func:`vsgjax.agents.dreamer.gate_objectives.gate_cell`).
    """

    cfg: ModelConfig
    name: str  # the model's (its registry entry's)
    precision: str = "float32"  # the run config's
    gate: GateCell = BERNOULLI_GATE

    def __post_init__(self):
        if self.cfg.hidden <= 0:
            raise ValueError(f"model.hidden must be positive, got {self.cfg.hidden}")
        if self.cfg.gate_mode not in GATE_MODES:
            raise ValueError(
                f"unknown model.gate_mode {self.cfg.gate_mode!r}; valid: {', '.join(GATE_MODES)}"
            )
        _ = self.latent  # LatentSpace raises on a bad stoch / classes
        _ = self.dtype  # raises on an unknown precision

    @property
    def dtype(self) -> jnp.dtype:
        """Compute dtype of the matmuls (``precision``)."""
        return compute_dtype(self.precision)

    @property
    def latent(self) -> LatentSpace:
        return LatentSpace(self.cfg.stoch, self.cfg.classes, self.cfg.min_std)

    @property
    @abc.abstractmethod
    def gated(self) -> bool:
        """Whether states carry gates (``vsg``, ``svsg``)."""

    @property
    @abc.abstractmethod
    def feat_dim(self) -> int:
        """Size of :meth:`feat`."""

    @abc.abstractmethod
    def init(self, key: jax.Array, embed_dim: int, action_dim: int) -> dict:
        """Parameters (plain nested dict)."""

    @abc.abstractmethod
    def initial(self) -> State:
        """The all-zero state that starts every episode."""

    @abc.abstractmethod
    def img_step(self, params: dict, prev: State, action: jax.Array, key: jax.Array) -> State:
        """Prior step: next state from the previous state and the action taken there."""

    @abc.abstractmethod
    def feat(self, state: State) -> jax.Array:
        """Feature vector ``[feat_dim]`` that the heads, actor and critic read."""

    def project_embed(self, params: dict, embed: jax.Array) -> jax.Array:
        """Embedding part of the posterior's first layer; ``[..., E] -> [..., hidden]``."""
        return dense(params["obs_embed"], embed, self.dtype)

    def _stats_init(self, keys: jax.Array, prior_in: int, context: str, context_dim: int,
                    embed_dim: int) -> dict:
        """The layers every model shares (five keys): the prior's hidden layer from
        ``prior_in`` features and its statistics, and the posterior's hidden layer from the
        prior's ``context`` and the embedding, and its statistics."""
        cfg, stats_dim = self.cfg, self.latent.stats_dim
        return {
            "img_out": dense_init(keys[0], prior_in, cfg.hidden),
            "img_stats": dense_init(keys[1], cfg.hidden, stats_dim),
            f"obs_{context}": dense_init(keys[2], context_dim, cfg.hidden),
            "obs_embed": dense_init(keys[3], embed_dim, cfg.hidden, bias=False),
            "obs_stats": dense_init(keys[4], cfg.hidden, stats_dim),
        }

    def _prior_dist(self, params: dict, prior_in: jax.Array):
        """``stats(ELU(Dense(prior_in)))``: the prior's distribution."""
        hidden = jax.nn.elu(dense(params["img_out"], prior_in, self.dtype))
        return self.latent.from_raw(dense(params["img_stats"], hidden, self.dtype))

    def _posterior_dist(self, params: dict, context: str, value: jax.Array,
                        embed_proj: jax.Array):
        """``stats(ELU(Dense([context, embed])))``: the posterior's distribution."""
        hidden = jax.nn.elu(dense(params[f"obs_{context}"], value, self.dtype) + embed_proj)
        return self.latent.from_raw(dense(params["obs_stats"], hidden, self.dtype))

    @abc.abstractmethod
    def _obs_step_projected(
        self, params: dict, prev: State, action: jax.Array, embed_proj: jax.Array, key: jax.Array
    ) -> tuple[State, State]:
        """:meth:`obs_step` given ``project_embed(params, embed)``."""

    def obs_step(
        self, params: dict, prev: State, action: jax.Array, embed: jax.Array, key: jax.Array
    ) -> tuple[State, State]:
        """Posterior step ``(post, prior)``; the prior is ``img_step`` from the same ``prev``."""
        embed_proj = self.project_embed(params, embed)
        return self._obs_step_projected(params, prev, action, embed_proj, key)

    def reset(
        self, state: State, action: jax.Array, is_first: jax.Array
    ) -> tuple[State, jax.Array]:
        """Zero the state and the previous action where ``is_first`` (a scalar bool)."""
        state = jax.tree.map(lambda zero, x: jnp.where(is_first, zero, x), self.initial(), state)
        return state, jnp.where(is_first, jnp.zeros_like(action), action)

    def observe(
        self,
        params: dict,
        embeds: jax.Array,
        actions: jax.Array,
        is_first: jax.Array,
        key: jax.Array,
        start: State | None = None,
    ) -> tuple[State, State]:
        """Posteriors and priors ``[T, ...]`` of a sequence, one ``lax.scan`` over time.

        ``actions[t]`` is the action that led to observation ``t``; where ``is_first[t]`` the
        previous state and action are zeroed before step ``t``. ``start`` defaults to
        :meth:`initial`.
        """
        prev = self.initial() if start is None else start
        projected = self.project_embed(params, embeds)
        keys = jax.random.split(key, embeds.shape[0])

        def step(prev, inputs):
            embed_proj, action, first, step_key = inputs
            prev, action = self.reset(prev, action, first)
            post, prior = self._obs_step_projected(params, prev, action, embed_proj, step_key)
            return post, (post, prior)

        _, (posts, priors) = jax.lax.scan(step, prev, (projected, actions, is_first, keys))
        return posts, priors

    def imagine(
        self, params: dict, policy: Policy, start: State, horizon: int, key: jax.Array
    ) -> tuple[State, jax.Array]:
        """Roll the prior under ``policy``: ``H + 1`` states and ``H + 1`` actions.

        ``states[0] = start``, ``actions[t] = policy(feat(states[t]))``,
        ``states[t + 1] = img_step(states[t], actions[t])``.
        """
        keys = jax.random.split(key, horizon + 1)

        def step(state, step_key):
            policy_key, img_key = jax.random.split(step_key)
            action = policy(self.feat(state), policy_key)
            return self.img_step(params, state, action, img_key), (state, action)

        last, (states, actions) = jax.lax.scan(step, start, keys[:-1])
        last_action = policy(self.feat(last), jax.random.split(keys[-1])[0])
        return _append(states, last), _append(actions, last_action)

    def rollout(
        self, params: dict, start: State, actions: jax.Array, key: jax.Array
    ) -> State:
        """Open-loop prior under given ``actions[H, A]``; ``states[t]`` follows ``actions[t]``."""

        def step(state, inputs):
            action, step_key = inputs
            state = self.img_step(params, state, action, step_key)
            return state, state

        keys = jax.random.split(key, actions.shape[0])
        _, states = jax.lax.scan(step, start, (actions, keys))
        return states

    def kl(self, post: State, prior: State) -> jax.Array:
        """``KL(post ‖ prior)`` per latent dimension (Gaussian dim or categorical variable)."""
        return post.dist.kl(prior.dist)

    def entropy(self, state: State) -> jax.Array:
        """Entropy of the state's latent distribution (scalar)."""
        return state.dist.entropy()

    def gates(self, state: State) -> tuple[jax.Array, jax.Array]:
        """``(g, p)``: straight-through gate sample and the probability that the gate opens
        (gated models only; :func:`~vsgjax.agents.dreamer.cells.open_probability`)."""
        logit = self.gate_logits(state)
        return state.gate, open_probability(self.gate, logit)

    def gate_logits(self, state: State) -> jax.Array:
        """Gate logits (the ReTanh gate: its pre-activation before the noise), for the
        numerically stable sparsity loss (:mod:`vsgjax.agents.dreamer.gates`)."""
        if not self.gated:
            raise ValueError(f"model {self.name!r} has no gates (gated: "
                             f"{', '.join(gated_models())})")
        return state.gate_logit
