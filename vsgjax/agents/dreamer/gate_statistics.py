"""Gate sparsity statistics of a gated world model (VSG, SVSG) on a batch of episodes.

    stats = gate_statistics(run.params, batch)                  # vsgjax.load(logdir).params
    stats = gate_statistics(state.params, batch, config=config)  # a world-model params dict
    stats.open_per_unit, stats.kl_per_unit, stats.closed_runs    # arrays, shapes below
    stats.summary()                                              # {"gates/open": ..., ...}

``batch`` holds ``[B, T, ...]`` arrays: the observation keys the params were built for,
``action`` ``[B, T, A]`` and ``is_first`` ``[B, T]`` (other keys are ignored).

Two passes over the batch, both with the gates sampled as in training (``model.gate_mode``):

* the posterior pass is :func:`vsgjax.observe` with the same ``key``, so its gates are those
  the world-model loss sees. Its prior shares the posterior's gate (the gate is computed in
  the prior step and never sees the observation), so it adds nothing here;
* the prior pass rolls the prior open loop from each sequence's start under the batch's
  actions (the state zeroed where ``is_first``, as in the posterior pass): the gates of
  imagination.

:func:`gate_statistics_core` is the pure, jittable part (``config`` static), for use inside a
compiled training step; :func:`gate_statistics` checks its inputs and calls it.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer.api import DEFAULT_SEED, TrainedParams, world_model_for
from vsgjax.agents.dreamer.gates import bernoulli_kl
from vsgjax.agents.dreamer.world_model import WorldModel, obs_spec_of
from vsgjax.agents.interface import AgentParams
from vsgjax.config import Config
from vsgjax.registry.agents import agent_entry, gated_models


@functools.partial(jax.tree_util.register_dataclass,
                   data_fields=("gate", "post_prob", "prior_gate", "prior_prob", "kl_per_unit",
                                "never_open", "always_open", "closed_runs"),
                   meta_fields=("model", "kappa"))
@dataclasses.dataclass(frozen=True)
class GateStatistics:
    """Gate statistics of a ``[B, T]`` batch; ``D`` gated units (VSG: ``model.deter``
    deterministic units, SVSG: ``model.stoch`` stochastic dimensions).

    * ``gate`` ``[B, T, D]``: posterior-pass gate samples, exactly 0 (closed: the unit keeps
      its value) or 1 (open: updated);
    * ``post_prob``, ``prior_prob`` ``[B, T, D]``: gate probability ``p = σ(logit)`` of the
      posterior and the open-loop prior pass; ``prior_gate`` ``[B, T, D]`` the prior's samples;
    * ``kl_per_unit`` ``[D]``: ``KL(Bern(p) ‖ Bern(κ))`` of the posterior pass per unit,
      averaged over ``B, T``; its sum over units is the loss's ``gate_kl`` metric;
    * ``never_open``, ``always_open`` ``[B]``: fraction of units whose gate stayed closed /
      open at every step of the sequence;
    * ``closed_runs`` ``[T]``: ``closed_runs[k - 1]`` counts the maximal runs of exactly ``k``
      consecutive closed steps of one unit (steps over which it keeps its value), over ``B``
      and ``D``. A run ends at an open step, at an episode start (the state is reset) or at
      the sequence's end (runs cut by the window edges count with their visible length).

    ``model`` and ``kappa`` (``wm.gate_kappa``) are static (pytree metadata).
    """

    gate: jax.Array
    post_prob: jax.Array
    prior_gate: jax.Array
    prior_prob: jax.Array
    kl_per_unit: jax.Array
    never_open: jax.Array
    always_open: jax.Array
    closed_runs: jax.Array
    model: str
    kappa: float

    @property
    def open_per_unit(self) -> jax.Array:
        """``[D]``: fraction of steps each unit's gate was open."""
        return self.gate.mean((0, 1))

    @property
    def open_per_step(self) -> jax.Array:
        """``[B, T]``: fraction of units open at each step; for SVSG the fraction of
        stochastic dimensions resampled (the rest are copied)."""
        return self.gate.mean(-1)

    @property
    def kl(self) -> jax.Array:
        """Gate KL summed over units, averaged over ``B, T`` (the ``gate_kl`` metric)."""
        return self.kl_per_unit.sum()

    def summary(self) -> dict[str, float]:
        """Scalars for logging, under ``gates/*`` keys (host floats)."""
        lengths = jnp.arange(1, self.closed_runs.shape[0] + 1)
        runs = self.closed_runs.sum()
        out = {
            "gates/open": self.gate.mean(),
            "gates/open_prior": self.prior_gate.mean(),
            "gates/prob_post": self.post_prob.mean(),
            # 0 when every gate is the same coin whatever the state: the gates respond to nothing
            "gates/prob_post_std": self.post_prob.std(),
            "gates/prob_prior": self.prior_prob.mean(),
            "gates/kl": self.kl,
            "gates/open_per_step_std": self.open_per_step.std(),
            "gates/open_per_unit_std": self.open_per_unit.std(),
            "gates/never_open": self.never_open.mean(),
            "gates/always_open": self.always_open.mean(),
            "gates/closed_run_mean": jnp.where(
                runs > 0, (lengths * self.closed_runs).sum() / jnp.maximum(runs, 1), 0.0),
        }
        if agent_entry(self.model).option("dynamics") == "SVSG":  # the gates update the state
            out["gates/stoch_updated"] = self.open_per_step.mean()
        return {key: float(value) for key, value in out.items()}


def closed_run_lengths(gate: jax.Array, is_first: jax.Array) -> jax.Array:
    """Histogram ``[T]`` of closed-run lengths of 0/1 gates ``[B, T, D]`` (see
    :class:`GateStatistics`); ``is_first`` ``[B, T]`` cuts runs at episode starts.

    ``count[t] = (count[t-1]·(1 - first[t]) + 1)·closed[t]`` is the length of the closed run
    that reaches step ``t``; the run ends at ``t`` unless step ``t + 1`` continues it.
    """
    closed = (gate < 0.5).astype(jnp.int32)
    first = is_first.astype(jnp.int32)[..., None] * jnp.ones_like(closed)

    def step(count, inputs):
        closed_t, first_t = inputs
        count = (count * (1 - first_t) + 1) * closed_t
        return count, count

    _, counts = jax.lax.scan(step, jnp.zeros_like(closed[:, 0]),
                             (jnp.moveaxis(closed, 1, 0), jnp.moveaxis(first, 1, 0)))
    counts = jnp.moveaxis(counts, 0, 1)  # [B, T, D]
    continues = jnp.concatenate([closed[:, 1:] * (1 - first[:, 1:]),
                                 jnp.zeros_like(closed[:, :1])], 1)
    ends = counts * (1 - continues)  # the run's length where it ends, else 0
    length = gate.shape[1]
    return jnp.zeros(length + 1, jnp.int32).at[ends.reshape(-1)].add(1)[1:]


def _prior_pass(model: WorldModel, dyn_params: dict, actions: jax.Array, is_first: jax.Array,
                key: jax.Array):
    """Open-loop prior of one sequence: ``(gates, logits)`` ``[T, D]``."""
    dyn = model.dynamics

    def step(state, inputs):
        action, first, step_key = inputs
        state, action = dyn.reset(state, action, first)
        state = dyn.img_step(dyn_params, state, action, step_key)
        return state, (state.gate, state.gate_logit)

    keys = jax.random.split(key, actions.shape[0])
    _, (gate, logit) = jax.lax.scan(step, dyn.initial(), (actions, is_first, keys))
    return gate, logit


@functools.partial(jax.jit, static_argnames="config")
def gate_statistics_core(config: Config, wm_params: dict, batch: Mapping,
                         key: jax.Array) -> GateStatistics:
    """:class:`GateStatistics` of world-model ``wm_params`` on a ``[B, T]`` batch (pure; no
    input checks: use :func:`gate_statistics`). The posterior pass uses ``key`` exactly as
    :func:`vsgjax.observe` does; the prior pass uses ``fold_in(key, 1)``."""
    actions = batch["action"].astype(jnp.float32)
    batch_size = actions.shape[0]
    model = world_model_for(config, wm_params, actions.shape[-1])
    dyn = model.dynamics
    seq = dict(batch, action=actions)
    posts, _ = jax.vmap(model.observe, in_axes=(None, 0, 0))(
        wm_params, seq, jax.random.split(key, batch_size))
    gate, logit = posts.gate, posts.gate_logit
    prior_keys = jax.random.split(jax.random.fold_in(key, 1), batch_size)
    prior_gate, prior_logit = jax.vmap(_prior_pass, in_axes=(None, None, 0, 0, 0))(
        model, wm_params["dynamics"], actions, batch["is_first"], prior_keys)
    gate, prior_gate = jax.lax.stop_gradient((gate, prior_gate))
    opened = gate.sum(1)  # [B, D]
    kappa = config.wm.gate_kappa
    return GateStatistics(
        gate=gate,
        post_prob=jax.nn.sigmoid(logit),
        prior_gate=prior_gate,
        prior_prob=jax.nn.sigmoid(prior_logit),
        kl_per_unit=bernoulli_kl(logit, kappa).mean((0, 1)),
        never_open=(opened == 0).mean(-1),
        always_open=(opened == gate.shape[1]).mean(-1),
        closed_runs=closed_run_lengths(gate, batch["is_first"]),
        model=dyn.cfg.name,
        kappa=kappa,
    )


def gate_statistics(params: TrainedParams | dict, batch: Mapping, key: jax.Array | None = None,
                    *, config: Config | None = None) -> GateStatistics:
    """:class:`GateStatistics` of a gated world model on a ``[B, T]`` batch of episodes.

    ``params``: the params of :func:`vsgjax.load` (they carry their config), or a world-model
    params dict (``TrainState.params``) with ``config=``.
    ``key`` defaults to ``PRNGKey(0)``. Raises ValueError for a model without gates and for a
    batch whose shapes do not match the params (naming the expected shapes).
    """
    if isinstance(params, TrainedParams):
        if config is not None and config != params.config:
            raise ValueError("config= differs from the config the TrainedParams carry; "
                             "leave config out")
        config, params = params.config, params.wm
    elif isinstance(params, AgentParams):  # another agent's run (vsgjax.load): no gates
        config = params.config
    elif config is None:
        raise TypeError("gate_statistics needs config= with a plain params dict (the "
                        "TrainedParams of vsgjax.load carry their config)")
    name = config.model.name
    if name not in gated_models():
        raise ValueError(f"model {name!r} has no gates: gate statistics exist only for the "
                         f"gated models ({', '.join(gated_models())})")
    _check_batch(config, params, batch)
    key = jax.random.PRNGKey(DEFAULT_SEED) if key is None else key
    keys = (*obs_spec_of(params).keys, "action", "is_first")
    return gate_statistics_core(config, params, {k: jnp.asarray(batch[k]) for k in keys}, key)


def _check_batch(config: Config, params: dict, batch: Mapping) -> None:
    """Raise ValueError naming the expected shapes unless ``batch`` is a ``[B, T]`` batch
    for these params."""
    spec = obs_spec_of(params)
    flat_dim = WorldModel(config, spec).dynamics.latent.flat_dim
    action_dim = params["dynamics"]["img_in"]["kernel"].shape[0] - flat_dim
    for key in ("action", "is_first"):
        if key not in batch:
            raise ValueError(f"the batch lacks {key!r}; expected keys {list(spec.keys)} "
                             f"[B, T, ...], 'action' [B, T, {action_dim}], 'is_first' [B, T]")
    first = tuple(jnp.shape(batch["is_first"]))
    if len(first) != 2:
        raise ValueError(f"'is_first' has shape {first}; expected [B, T] (one episode [T]: "
                         f"add a leading axis, jax.tree.map(lambda x: x[None], episode))")
    action = tuple(jnp.shape(batch["action"]))
    if action != (*first, action_dim):
        raise ValueError(f"'action' has shape {action}; expected [B, T, A] = "
                         f"{[*first, action_dim]} (the model's action size is {action_dim})")
    leads = spec.check(batch)
    if tuple(leads) != first:
        raise ValueError(f"observations have leading dims {tuple(leads)}; expected [B, T] = "
                         f"{list(first)} like 'is_first' (shapes {spec.shapes} after them)")
