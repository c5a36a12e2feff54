"""Gate sparsity statistics of a gated world model (VSG, SVSG) on a batch of episodes.

    stats = gate_statistics(run.params, batch)                  # vsgjax.load(logdir).params
    stats = gate_statistics(state.params, batch, config=config)  # a world-model params dict
    stats.open_per_unit, stats.kl_per_unit, stats.closed_runs    # arrays, shapes below
    stats.summary()                                              # {"gates/open": ..., ...}
    stats.holding(gap)               # fraction of units closed across gap steps
    stats.holding(gap, live_only=True)  # of the units that ever opened (stats.live)
    stats.prob_at_step(1)            # gate probability at episode step 1, at the others
    stats.written_and_held(gap)      # units written at steps 1-2 and closed for gap steps

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
import math
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.agents.dreamer.cells import BERNOULLI, open_probability
from vsgjax.agents.dreamer.gates import bernoulli_kl, probability_kl
from vsgjax.agents.dreamer.inference import DEFAULT_SEED, world_model_for
from vsgjax.agents.dreamer.trained_params import TrainedParams
from vsgjax.agents.dreamer.world_model import WorldModel, obs_spec_of
from vsgjax.agents.interface import AgentParams
from vsgjax.config import Config
from vsgjax.registry.agents import agent_entry, gated_models


@functools.partial(jax.tree_util.register_dataclass,
                   data_fields=("gate", "post_prob", "prior_gate", "prior_prob", "kl_per_unit",
                                "never_open", "always_open", "closed_runs", "longest_closed",
                                "is_first"),
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
      the sequence's end (runs cut by the window edges count with their visible length);
    * ``longest_closed`` ``[B, D]``: each unit's longest closed run in the sequence;
    * ``is_first`` ``[B, T]``: the batch's episode starts.

    "Open" is the gate that updates the unit: the Bernoulli sample, or GateL0RD's ``Θ(Λ)``
    (``Λ > 0``; ``wm.gate_objective=gatel0rd``), whose probability is ``P(u + ε > 0)``.
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
    longest_closed: jax.Array
    is_first: jax.Array
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

    @property
    def live(self) -> jax.Array:
        """``[D]``: units whose gate opened at least once in the batch. The others are dead:
        they keep their initial value whatever comes, so they count as closed everywhere and
        make any gap look held; the ``live`` statistics leave them out."""
        return self.gate.max((0, 1)) > 0

    def _units(self, live_only: bool) -> jax.Array:
        """``[D]``: the :attr:`live` units, or every unit."""
        return self.live if live_only else jnp.ones(self.gate.shape[-1], bool)

    def open_live(self) -> jax.Array:
        """The open rate of the live units (0 when none is live)."""
        steps = self.gate.shape[0] * self.gate.shape[1]
        return (self.gate * self.live).sum() / jnp.maximum(self.live.sum() * steps, 1)

    def holding(self, gap: int, live_only: bool = False) -> jax.Array:
        """Fraction of units (over ``B, D``; only the :attr:`live` ones with ``live_only``, 0
        when none is) closed for at least ``gap`` consecutive steps of one episode: units that
        kept a value across a memory gap of ``gap`` steps."""
        if gap < 1:
            raise ValueError(f"a holding gap is a number of steps >= 1, got {gap}")
        units = self._units(live_only)
        held = (self.longest_closed >= gap) * units
        return held.sum() / jnp.maximum(units.sum() * held.shape[0], 1)

    def written_and_held(self, gap: int) -> jax.Array:
        """Fraction of ``(episode, unit)`` pairs whose gate opened at episode step 1 or 2 and
        then stayed closed for the ``gap`` steps after step 2: units that stored what steps 0
        and 1 show (a MemoryChain cue; step ``t``'s gate reads the posterior of ``t - 1``) and
        kept it. Over the episodes whose steps 1 to ``gap + 2`` all lie in the window; NaN when
        none does. Unlike :meth:`holding`, a unit closed all along (dead, or holding its reset
        value) does not count. Independent gates: :func:`null_written_and_held`."""
        if gap < 1:
            raise ValueError(f"a holding gap is a number of steps >= 1, got {gap}")
        count = self.gate.shape[1] - gap - 1  # positions t of step 1 whose step gap + 2 fits
        if count < 1:
            return jnp.asarray(jnp.nan)
        zero = jnp.zeros_like(self.gate[:, :1])
        opened = jnp.concatenate([zero, jnp.cumsum(self.gate, 1)], 1)
        starts = jnp.concatenate([zero[..., 0], jnp.cumsum(self.is_first, 1)], 1)
        t = jnp.arange(count)
        written = (self.gate[:, t] + self.gate[:, t + 1]) > 0
        closed_after = opened[:, t + gap + 2] == opened[:, t + 2]
        whole = (self.episode_steps()[:, t] == 1) & (starts[:, t + gap + 2] == starts[:, t + 1])
        held = (written & closed_after & whole[..., None]).sum()
        episodes = whole.sum()
        return jnp.where(episodes > 0, held / jnp.maximum(episodes * self.gate.shape[-1], 1),
                         jnp.nan)

    def rates(self) -> dict[str, jax.Array]:
        """GateL0RD's three rates: the fraction of open ``(b, t, unit)`` entries, of steps
        with any unit open, and of units opened at least once in a sequence."""
        return {"open": self.gate.mean(), "steps_any_open": (self.gate.max(-1) > 0).mean(),
                "units_ever_open": 1.0 - self.never_open.mean()}

    def episode_steps(self) -> jax.Array:
        """``[B, T]``: each step's index in its episode (0 at ``is_first``); -1 before the
        sequence's first episode start, whose position is unknown."""
        index = jnp.arange(self.is_first.shape[1])
        start = jax.lax.cummax(jnp.where(self.is_first, index, -1), axis=1)
        return jnp.where(start >= 0, index - start, -1)

    def prob_at_step(self, step: int, live_only: bool = False) -> tuple[jax.Array, jax.Array]:
        """Mean posterior gate probability at episode step ``step`` and at the other steps of
        known position (over ``B``, those steps and ``D``, or the :attr:`live` units with
        ``live_only``; NaN where there are none).

        The gate of step ``t`` is computed before observation ``t`` is seen (from the
        posterior of ``t - 1``): the gate that can store what step 0 shows is step 1's.
        """
        if step < 0:
            raise ValueError(f"an episode step is >= 0, got {step}")
        steps = self.episode_steps()[..., None]
        units = self._units(live_only)
        at, other = (steps == step) & units, (steps >= 0) & (steps != step) & units
        mean = lambda mask: (self.post_prob * mask).sum() / mask.sum()
        return mean(at), mean(other)

    def segments(self) -> list[list[int]]:
        """Per sequence, the lengths of its episode segments: the window cut at each episode
        start after its first step (one segment ``[T]`` where the window holds no start)."""
        rows = []
        for first in np.asarray(jax.device_get(self.is_first), bool):
            cuts = [0, *np.flatnonzero(first[1:]) + 1, len(first)]
            rows.append(np.diff(cuts).tolist())
        return rows

    def closed_run_quantiles(self) -> dict[str, float]:
        """The closed runs' mean, 90th percentile and max, and the same for the geometric
        null of independent gates with the same open rate in the same episode segments
        (:func:`geometric_null`)."""
        counts = np.asarray(jax.device_get(self.closed_runs), float)
        runs, lengths = counts.sum(), np.arange(1, len(counts) + 1)
        observed = {"mean": 0.0, "p90": 0.0, "max": 0.0}
        if runs:
            observed = {"mean": float((lengths * counts).sum() / runs),
                        "p90": float(lengths[np.argmax(counts.cumsum() >= 0.9 * runs)]),
                        "max": float(lengths[np.flatnonzero(counts)[-1]])}
        segments = [length for row in self.segments() for length in row]
        null = geometric_null(float(self.gate.mean()), int(runs), segments)
        return {**{f"closed_run_{k}": v for k, v in observed.items()},
                **{f"null_run_{k}": v for k, v in null.items()}}

    def summary(self, gaps: Sequence[int] | None = None, memory_gap: int = 0
                ) -> dict[str, float]:
        """Scalars for logging, under ``gates/*`` keys (host floats); ``gates/holding_<gap>``
        and the same for independent gates, ``gates/null_holding_<gap>`` (:func:`null_holding`),
        for each gap of ``gaps`` (default: those of :data:`HOLDING_GAPS` the window can
        show) and a task's ``memory_gap`` if it fits; where the batch shows episode starts,
        the mean posterior gate probability at episode step 1 (the gate that can store what
        the first observation shows: MemoryChain's cue) and at the other steps,
        ``gates/prob_step1`` and ``gates/prob_other_steps``. The same over the :attr:`live`
        units only, under ``gates/live_*`` (``gates/live_units`` their fraction,
        ``gates/open_live`` their open rate, the null at that rate): dead units look held.

        With a ``memory_gap`` of ``L`` (a cue shown at episode step 0, asked for at step
        ``L + 1``) whose episodes fit the window, ``gates/written_and_held_<L>``: the units
        written at step 1 or 2 and closed to step ``L + 1``
        (:meth:`written_and_held` over ``L - 1`` steps), and ``gates/null_written_and_held_<L>``
        for independent gates at the open rate.

        Every null is that of independent gates in this batch's episode segments: an episode
        start cuts closed runs (:meth:`segments`)."""
        lengths = jnp.arange(1, self.closed_runs.shape[0] + 1)
        runs = self.closed_runs.sum()
        window = self.gate.shape[1]
        gaps = [g for g in HOLDING_GAPS if g <= window] if gaps is None else list(gaps)
        if 0 < memory_gap <= window and memory_gap not in gaps:
            gaps.append(memory_gap)
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
        rates = self.rates()
        out.update({"gates/steps_any_open": rates["steps_any_open"],
                    "gates/units_ever_open": rates["units_ever_open"]})
        out.update({f"gates/{key}": value for key, value in self.closed_run_quantiles().items()
                    if key != "closed_run_mean"})
        live_rate = float(self.open_live())
        out.update({"gates/live_units": self.live.mean(), "gates/open_live": live_rate})
        for prefix, live_only in (("", False), ("live_", True)):
            cue, other = self.prob_at_step(1, live_only)
            if jnp.isfinite(cue) and jnp.isfinite(other):  # episode starts (and live units)
                out.update({f"gates/{prefix}prob_step1": cue,
                            f"gates/{prefix}prob_other_steps": other})
        open_rate, segments = float(self.gate.mean()), self.segments()
        for gap in gaps:
            out[f"gates/holding_{gap}"] = self.holding(gap)
            out[f"gates/null_holding_{gap}"] = null_holding_in(open_rate, gap, segments)
            out[f"gates/live_holding_{gap}"] = self.holding(gap, live_only=True)
            out[f"gates/live_null_holding_{gap}"] = null_holding_in(live_rate, gap, segments)
        if memory_gap > 0:
            held = self.written_and_held(max(1, memory_gap - 1))
            if jnp.isfinite(held):  # an episode's steps 1 to L + 1 fit the window
                out[f"gates/written_and_held_{memory_gap}"] = held
                out[f"gates/null_written_and_held_{memory_gap}"] = null_written_and_held(
                    open_rate, max(1, memory_gap - 1))
        return {key: float(value) for key, value in out.items()}


# Memory gaps (steps) the summary reports gates/holding_<gap> for, where the window fits them.
HOLDING_GAPS = (5, 10, 20, 50)


def null_holding(open_rate: float, gap: int, window: int) -> float:
    """Probability that a unit whose gate opens independently with probability ``open_rate``
    at each of ``window`` steps is closed for ``gap`` consecutive steps at least once: the
    :meth:`GateStatistics.holding` of independent gates in windows without an episode start
    inside (:func:`null_holding_in` with them)."""
    if gap < 1:
        raise ValueError(f"a holding gap is a number of steps >= 1, got {gap}")
    run = np.zeros(gap)  # probability of a current closed run of r < gap steps, not yet held
    run[0], held = 1.0, 0.0
    for _ in range(window):
        closed = run * (1.0 - open_rate)
        held += closed[-1]
        run = np.concatenate([[run.sum() * open_rate], closed[:-1]])
    return float(held)


def null_holding_in(open_rate: float, gap: int, rows: Sequence[Sequence[int]]) -> float:
    """:func:`null_holding` in windows cut by episode starts: ``rows`` holds each window's
    episode segment lengths (:meth:`GateStatistics.segments`); a unit holds in a window if
    it does in one of its segments, independently. The mean over the windows."""
    if not rows:
        raise ValueError("null_holding_in needs at least one window of episode segments")
    return float(np.mean([1.0 - np.prod([1.0 - null_holding(open_rate, gap, length)
                                         for length in row]) for row in rows]))


def window_segments(episode_steps: int, window: int) -> list[list[int]]:
    """The episode segments of a ``window``-step sequence over back-to-back episodes of
    ``episode_steps`` stored steps, one row per step of an episode the window can start at
    (rows equally likely for windows that start anywhere): a null's segments for a replay
    that is not at hand (:func:`null_holding_in`, :func:`geometric_null`)."""
    if episode_steps < 1 or window < 1:
        raise ValueError(f"episode_steps and window are >= 1, got {episode_steps}, {window}")
    return [np.diff([0, *range(episode_steps - offset, window, episode_steps), window]).tolist()
            for offset in range(episode_steps)]


def expected_closed_runs(open_rate: float, segments: Sequence[int]) -> float:
    """Expected closed runs of one unit whose gate opens independently with probability
    ``q = open_rate`` over episode segments of these lengths: a run starts at a segment's
    first step if closed, and at any later closed step after an open one,
    ``(1 - q)(1 + (s - 1) q)`` per segment of ``s`` steps."""
    return float(sum((1.0 - open_rate) * (1.0 + (s - 1) * open_rate) for s in segments))


def null_written_and_held(open_rate: float, gap: int) -> float:
    """:meth:`GateStatistics.written_and_held` of gates that open independently with
    probability ``open_rate`` at each step: open at step 1 or 2, then closed ``gap`` steps."""
    closed = 1.0 - open_rate
    return float((1.0 - closed ** 2) * closed ** gap)


def geometric_null(open_rate: float, runs: int, segments: int | Sequence[int]
                   ) -> dict[str, float]:
    """Closed-run statistics of gates that open independently with probability ``q =
    open_rate`` at each step, whose closed runs are geometric: ``P(k) = (1 - q)^(k - 1) q``,
    over episode segments of these lengths (an int: one window of ``T`` steps without an
    episode start).

    ``mean``: the mean of the closed runs the segments show, pooled as
    :meth:`GateStatistics.closed_run_quantiles` pools them: the expected closed steps over the
    expected runs (:func:`expected_closed_runs`), ``Σ s / Σ (1 + (s - 1) q)``, for one window
    ``T / (1 + (T - 1) q)``, which is ``1 / q`` for long windows and ``T`` when the gates never
    open (a segment's edges cut runs: the uncut mean ``1 / q`` would exceed what any window can
    show once ``1 / q > T``). ``p90`` the smallest ``k`` with ``1 - (1 - q)^k >= 0.9``; ``max``
    the median of the longest of ``runs`` such runs, the smallest ``k`` with
    ``(1 - (1 - q)^k)^runs >= 1/2``; both capped at the longest segment: upper bounds for the
    runs the segments cut, which are shorter.
    """
    if not 0.0 <= open_rate <= 1.0:
        raise ValueError(f"an open rate lies in [0, 1], got {open_rate}")
    segments = [segments] if isinstance(segments, int) else list(segments)
    if not segments or min(segments) < 1:
        raise ValueError(f"segments are lengths >= 1, got {segments}")
    longest_segment = max(segments)
    if open_rate == 1.0:
        return {"mean": 1.0, "p90": 1.0, "max": 1.0}
    mean = sum(segments) * (1.0 - open_rate) / expected_closed_runs(open_rate, segments)
    if open_rate == 0.0:
        return {"mean": mean, "p90": float(longest_segment), "max": float(longest_segment)}
    log_closed = math.log1p(-open_rate)

    def first_k(log_tail: float) -> float:
        """The smallest ``k`` (>= 1, <= the longest segment) with ``(1 - q)^k <=
        exp(log_tail)``."""
        return float(min(longest_segment, max(1, math.ceil(log_tail / log_closed - 1e-9))))

    # (1 - (1 - q)^k)^runs >= 1/2  <=>  (1 - q)^k <= 1 - 2^(-1/runs)
    longest = first_k(math.log(-math.expm1(math.log(0.5) / max(runs, 1))))
    return {"mean": mean, "p90": first_k(math.log(0.1)), "max": longest}


def _closed_counts(gate: jax.Array, is_first: jax.Array):
    """``(closed, first, counts)`` ``[B, T, D]`` int32: ``counts[t]`` is the length of the
    closed run that reaches step ``t``, ``(count[t-1]·(1 - first[t]) + 1)·closed[t]``."""
    closed = (gate < 0.5).astype(jnp.int32)
    first = is_first.astype(jnp.int32)[..., None] * jnp.ones_like(closed)

    def step(count, inputs):
        closed_t, first_t = inputs
        count = (count * (1 - first_t) + 1) * closed_t
        return count, count

    _, counts = jax.lax.scan(step, jnp.zeros_like(closed[:, 0]),
                             (jnp.moveaxis(closed, 1, 0), jnp.moveaxis(first, 1, 0)))
    return closed, first, jnp.moveaxis(counts, 0, 1)


def longest_closed_runs(gate: jax.Array, is_first: jax.Array) -> jax.Array:
    """``[B, D]``: each unit's longest closed run (cut at episode starts) in 0/1 gates
    ``[B, T, D]``."""
    return _closed_counts(gate, is_first)[2].max(1)


def closed_run_lengths(gate: jax.Array, is_first: jax.Array) -> jax.Array:
    """Histogram ``[T]`` of closed-run lengths of 0/1 gates ``[B, T, D]`` (see
    :class:`GateStatistics`); ``is_first`` ``[B, T]`` cuts runs at episode starts.

    The run ends at step ``t`` unless step ``t + 1`` continues it.
    """
    closed, first, counts = _closed_counts(gate, is_first)
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
    post_prob = open_probability(dyn.gate, logit)
    kl = (bernoulli_kl(logit, kappa) if dyn.gate.kind == BERNOULLI
          else probability_kl(post_prob, kappa))
    return GateStatistics(
        gate=gate,
        post_prob=post_prob,
        prior_gate=prior_gate,
        prior_prob=open_probability(dyn.gate, prior_logit),
        kl_per_unit=kl.mean((0, 1)),
        never_open=(opened == 0).mean(-1),
        always_open=(opened == gate.shape[1]).mean(-1),
        closed_runs=closed_run_lengths(gate, batch["is_first"]),
        longest_closed=longest_closed_runs(gate, batch["is_first"]),
        is_first=jnp.asarray(batch["is_first"], bool),
        model=dyn.name,
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
    name = config.agent
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
