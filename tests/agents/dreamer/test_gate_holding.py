"""Gate statistics that show holding (vsgjax/agents/dreamer/gate_statistics.py): closed runs
against the geometric null, GateL0RD's three rates, units closed across a gap, the gate
probability at a cue step, on hand-made gate sequences; and the statistics of a gatel0rd
model."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vsgjax
from vsgjax.agents.dreamer.gate_statistics import (
    HOLDING_GAPS,
    GateStatistics,
    closed_run_lengths,
    expected_closed_runs,
    gate_statistics,
    geometric_null,
    longest_closed_runs,
    null_holding,
    null_holding_in,
    null_written_and_held,
    window_segments,
)
from vsgjax.config import make_config


def hand_made(gate, is_first, prob=None) -> GateStatistics:
    """Statistics of given 0/1 gates ``[B, T, D]`` (the prior's equal to the posterior's)."""
    gate, is_first = jnp.asarray(gate, jnp.float32), jnp.asarray(is_first, bool)
    prob = gate if prob is None else jnp.asarray(prob, jnp.float32)
    opened = gate.sum(1)
    return GateStatistics(
        gate=gate, post_prob=prob, prior_gate=gate, prior_prob=prob,
        kl_per_unit=jnp.zeros(gate.shape[-1]), never_open=(opened == 0).mean(-1),
        always_open=(opened == gate.shape[1]).mean(-1),
        closed_runs=closed_run_lengths(gate, is_first),
        longest_closed=longest_closed_runs(gate, is_first), is_first=is_first,
        model="vsg", kappa=0.4)


def held_for_30(cut_at: int | None = None) -> GateStatistics:
    """Two units over 40 steps from an episode start: unit 0 open at steps 0-4 and 35-39 and
    closed for the 30 steps between; unit 1 always open. ``cut_at``: another episode start."""
    gate = np.ones((1, 40, 2))
    gate[0, 5:35, 0] = 0
    is_first = np.zeros((1, 40), bool)
    is_first[0, 0] = True
    if cut_at is not None:
        is_first[0, cut_at] = True
    return hand_made(gate, is_first)


def test_a_unit_closed_for_30_steps_holds_a_gap_of_20_and_not_of_31():
    stats = held_for_30()
    assert np.flatnonzero(stats.closed_runs).tolist() == [29]  # one run, of 30 steps
    np.testing.assert_array_equal(stats.longest_closed, [[30, 0]])
    assert float(stats.holding(20)) == 0.5  # one of the two units
    assert float(stats.holding(30)) == 0.5 and float(stats.holding(31)) == 0.0
    summary = stats.summary(gaps=[20, 31])
    assert summary["gates/holding_20"] == 0.5 and summary["gates/holding_31"] == 0.0
    assert summary["gates/closed_run_mean"] == summary["gates/closed_run_max"] == 30.0


def test_an_episode_start_cuts_the_run_so_it_holds_nothing_across_it():
    stats = held_for_30(cut_at=20)  # the state is reset at step 20: runs of 15 and 15
    np.testing.assert_array_equal(stats.longest_closed, [[15, 0]])
    assert float(stats.holding(20)) == 0.0 and float(stats.holding(15)) == 0.5


def test_gatel0rds_three_rates():
    gate = np.zeros((2, 4, 3))
    gate[0, 1, 0] = gate[0, 1, 1] = gate[0, 3, 0] = 1  # sequence 0: steps 1, 3; units 0, 1
    # sequence 1 never opens
    rates = {k: float(v) for k, v in hand_made(gate, np.zeros((2, 4), bool)).rates().items()}
    assert rates == pytest.approx({"open": 3 / 24, "steps_any_open": 2 / 8,
                                   "units_ever_open": (2 / 3 + 0) / 2})


@pytest.mark.parametrize("q, p90", [(0.5, 4), (0.4, 5), (0.1, 22)])
def test_the_geometric_nulls_mean_is_one_over_the_open_rate_in_long_windows(q, p90):
    null = geometric_null(q, runs=1, segments=10**6)
    assert null["mean"] == pytest.approx(1 / q, rel=1e-4)
    assert null["p90"] == p90 == math.ceil(math.log(0.1) / math.log(1 - q))
    assert (1 - q) ** p90 <= 0.1 < (1 - q) ** (p90 - 1)
    assert null["max"] == math.ceil(math.log(0.5) / math.log(1 - q))  # the median of one run
    more = geometric_null(q, runs=1000, segments=1000)["max"]
    assert (1 - (1 - q) ** more) ** 1000 >= 0.5 > (1 - (1 - q) ** (more - 1)) ** 1000
    assert geometric_null(q, runs=10**6, segments=10)["max"] == 10  # capped at the window
    assert geometric_null(0.0, 5, 30) == {"mean": 30.0, "p90": 30.0, "max": 30.0}


@pytest.mark.parametrize("q, window", [(0.02, 7), (0.05, 12), (0.4, 32), (0.9, 5)])
def test_the_nulls_mean_is_what_short_windows_of_independent_gates_show(q, window):
    """A rarely open gate in a short window: its runs are cut by the window's edges, so the
    null's mean stays within the window (1 / 0.02 = 50 would not fit 7 steps)."""
    gate = jax.random.bernoulli(jax.random.PRNGKey(1), q, (2000, window, 16))
    first = np.zeros((2000, window), bool)
    first[:, 0] = True
    seen = hand_made(gate.astype(jnp.float32), first).closed_run_quantiles()
    assert seen["null_run_mean"] <= window
    assert seen["closed_run_mean"] == pytest.approx(seen["null_run_mean"], rel=0.03)


def test_independent_gates_match_the_null_and_a_holding_unit_does_not():
    q, shape = 0.3, (40, 400, 8)
    gate = jax.random.bernoulli(jax.random.PRNGKey(0), q, shape).astype(jnp.float32)
    first = np.zeros(shape[:2], bool)
    first[:, 0] = True
    coin = hand_made(gate, first).closed_run_quantiles()
    assert coin["closed_run_mean"] == pytest.approx(coin["null_run_mean"], rel=0.03)
    assert abs(coin["closed_run_p90"] - coin["null_run_p90"]) <= 1
    assert abs(coin["closed_run_max"] - coin["null_run_max"]) <= 0.2 * coin["null_run_max"]
    held = hand_made(gate.at[:, 10:210, 0].set(0.0), first).closed_run_quantiles()
    assert held["closed_run_max"] >= 200 > 3 * held["null_run_max"]


def test_the_gate_probability_at_the_cue_step_against_the_other_steps():
    """Episodes start at steps 2 and 7 of a 10-step window; the probability is 0.9 at each
    episode's step 1 and 0.1 elsewhere; steps 0-1 come before the first start (unknown
    position, left out) and hold 0.5."""
    prob = np.full((1, 10, 2), 0.1)
    prob[0, [3, 8]] = 0.9
    prob[0, :2] = 0.5
    is_first = np.zeros((1, 10), bool)
    is_first[0, [2, 7]] = True
    stats = hand_made(np.zeros((1, 10, 2)), is_first, prob)
    np.testing.assert_array_equal(stats.episode_steps(), [[-1, -1, 0, 1, 2, 3, 4, 0, 1, 2]])
    at, other = stats.prob_at_step(1)
    assert float(at) == pytest.approx(0.9) and float(other) == pytest.approx(0.1)
    assert np.isnan(float(stats.prob_at_step(9)[0]))  # no episode reaches step 9
    summary = stats.summary()
    assert summary["gates/prob_step1"] == pytest.approx(0.9)
    assert summary["gates/prob_other_steps"] == pytest.approx(0.1)
    with pytest.raises(ValueError, match="-1"):
        stats.prob_at_step(-1)
    with pytest.raises(ValueError, match="got 0"):
        stats.holding(0)


def test_the_summary_keeps_its_keys_and_adds_the_holding_ones():
    stats = held_for_30()
    summary = stats.summary()
    assert {f"gates/holding_{g}" for g in HOLDING_GAPS if g <= 40} <= set(summary)
    assert "gates/holding_50" not in summary  # a 40-step window cannot show it
    assert summary["gates/open"] == pytest.approx(50 / 80)
    assert summary["gates/null_run_mean"] == pytest.approx(40 / (1 + 39 * 50 / 80))
    assert summary["gates/steps_any_open"] == 1.0 and summary["gates/units_ever_open"] == 1.0
    assert "gates/holding_30" not in summary
    assert stats.summary(memory_gap=30)["gates/holding_30"] == 0.5  # the task's memory gap
    assert "gates/holding_41" not in stats.summary(memory_gap=41)  # longer than the window


def test_statistics_of_a_gatel0rd_model():
    cfg = make_config("bbs_basic", "vsg", "debug", ["wm.gate_objective=gatel0rd"])
    params = vsgjax.init(cfg, jax.random.PRNGKey(0), obs_shape={"vector": (6,)},
                         action_dim=2).params
    rng = np.random.default_rng(0)
    is_first = np.zeros((3, 12), bool)
    is_first[:, 0] = True
    batch = {"vector": rng.normal(size=(3, 12, 6)).astype(np.float32),
             "action": rng.uniform(-1, 1, (3, 12, 2)).astype(np.float32), "is_first": is_first}
    stats = gate_statistics(params, batch, config=cfg)
    posts, _ = vsgjax.observe(cfg, params, batch, jax.random.PRNGKey(0))
    assert set(np.unique(stats.gate)) == {0.0, 1.0}
    np.testing.assert_allclose(stats.post_prob,
                               jax.scipy.stats.norm.cdf(posts.gate_logit / cfg.wm.gate_noise),
                               rtol=1e-4, atol=1e-7)
    summary = stats.summary()
    assert all(np.isfinite(v) for v in summary.values()) and 0 < summary["gates/open"] < 1


def test_the_null_holding_is_the_chance_that_independent_gates_stay_closed_for_the_gap():
    assert null_holding(0.3, 1, 1) == pytest.approx(0.7)
    assert null_holding(0.3, 3, 3) == pytest.approx(0.7**3)
    # window 4, gap 3: closed 1-3 or (anything at 1, open at 1 then) closed 2-4 -> 0.7³ + 0.3·0.7³
    assert null_holding(0.3, 3, 4) == pytest.approx(0.7**3 + 0.3 * 0.7**3)
    assert null_holding(0.3, 5, 4) == 0.0
    gate = jax.random.bernoulli(jax.random.PRNGKey(2), 0.3, (200, 32, 20)).astype(jnp.float32)
    first = np.zeros((200, 32), bool)
    measured = float(hand_made(gate, first).holding(10))
    assert measured == pytest.approx(null_holding(0.3, 10, 32), abs=0.02)
    summary = hand_made(gate, first).summary(gaps=[10])
    assert summary["gates/null_holding_10"] == pytest.approx(null_holding(
        summary["gates/open"], 10, 32))


def test_dead_units_are_left_out_of_the_live_statistics():
    """Four units over 12 steps of 4 sequences: two never open (dead: closed at every step,
    so they look held); unit 2 opens at step 1 of each episode only and holds for the other
    10 steps; unit 3 opens at every step. The whole population holds a 10-step gap at 3 of 4
    units' rate, the live units at half; the cue probability of the live units is theirs."""
    gate = np.zeros((4, 12, 4))
    gate[:, 1, 2] = 1.0
    gate[:, :, 3] = 1.0
    prob = np.where(gate > 0, 0.8, 0.05)
    first = np.zeros((4, 12), bool)
    first[:, 0] = True
    stats = hand_made(gate, first, prob)
    np.testing.assert_array_equal(stats.live, [False, False, True, True])
    assert float(stats.holding(10)) == pytest.approx(0.75)
    assert float(stats.holding(10, live_only=True)) == pytest.approx(0.5)
    assert float(stats.open_live()) == pytest.approx((1 + 12) / 24)
    summary = stats.summary(gaps=[10])
    assert summary["gates/live_units"] == 0.5
    assert summary["gates/live_holding_10"] == pytest.approx(0.5)
    assert summary["gates/live_null_holding_10"] == pytest.approx(
        null_holding(13 / 24, 10, 12))
    assert summary["gates/live_prob_step1"] == pytest.approx(0.8)  # both live units open
    assert summary["gates/prob_step1"] == pytest.approx((0.8 * 2 + 0.05 * 2) / 4)
    assert summary["gates/live_prob_other_steps"] == pytest.approx((0.05 * 10 + 0.8 * 10) / 20)
    none_live = hand_made(np.zeros((2, 12, 3)), first[:2]).summary(gaps=[10])
    assert none_live["gates/live_units"] == 0.0 and none_live["gates/live_holding_10"] == 0.0
    assert "gates/live_prob_step1" not in none_live  # no live unit to average


def test_a_unit_written_at_the_cue_and_kept_counts_and_a_dead_one_does_not():
    """One episode of 8 steps, gap 4 (steps 3-6 closed after a write at step 1 or 2): unit 0
    writes at step 1 and holds, unit 1 writes at step 2 and holds, unit 2 writes and opens again
    at step 5, unit 3 never opens (it holds nothing, though :meth:`holding` counts it)."""
    gate = np.zeros((1, 8, 4))
    gate[0, 1, 0] = gate[0, 2, 1] = gate[0, 1, 2] = gate[0, 5, 2] = 1
    first = np.zeros((1, 8), bool)
    first[0, 0] = True
    stats = hand_made(gate, first)
    assert float(stats.written_and_held(4)) == pytest.approx(2 / 4)
    assert float(stats.holding(4)) == pytest.approx(3 / 4)
    assert math.isnan(float(stats.written_and_held(6)))  # steps 1 to 8 do not fit in 8 steps
    # an episode start inside the gap: that episode is not counted
    first[0, 4] = True
    assert math.isnan(float(hand_made(gate, first).written_and_held(4)))
    # a window that starts mid-episode and one with two whole episodes
    gate2 = np.concatenate([gate, gate], 1)
    first2 = np.zeros((1, 16), bool)
    first2[0, [0, 8]] = True
    assert float(hand_made(gate2, first2).written_and_held(4)) == pytest.approx(2 / 4)
    assert math.isnan(float(hand_made(gate2[:, 3:], first2[:, 3:]).written_and_held(7)))


def test_independent_gates_write_and_hold_as_the_null_says():
    q, gap = 0.3, 5
    gate = jax.random.bernoulli(jax.random.PRNGKey(0), q, (4000, gap + 3, 8))
    first = np.zeros((4000, gap + 3), bool)
    first[:, 0] = True
    observed = float(hand_made(gate, first).written_and_held(gap))
    assert observed == pytest.approx(null_written_and_held(q, gap), abs=0.005)
    assert null_written_and_held(q, gap) == pytest.approx((1 - 0.7 ** 2) * 0.7 ** 5)


def test_episode_starts_cut_the_windows_segments():
    first = np.zeros((2, 10), bool)
    first[0, [0, 4]] = True
    first[1, 7] = True
    assert hand_made(np.ones((2, 10, 1)), first).segments() == [[4, 6], [7, 3]]
    assert window_segments(4, 10) == [[4, 4, 2], [3, 4, 3], [2, 4, 4], [1, 4, 4, 1]]
    assert all(sum(row) == 64 for row in window_segments(22, 64))
    with pytest.raises(ValueError, match="got 0, 64"):
        window_segments(0, 64)


def test_the_nulls_of_independent_gates_in_short_episodes_match_sampled_gates():
    """Independent gates at 0.2 over 48-step windows of 12-step episodes (starts at 0, 12, 24,
    36): the units closed for 8 steps, the closed runs' mean, their count and the written-and-
    held units are those the nulls give for these segments, below a window's nulls
    without episode starts."""
    q, gap = 0.2, 8
    gate = jax.random.bernoulli(jax.random.PRNGKey(3), q, (400, 48, 16)).astype(jnp.float32)
    first = np.zeros((400, 48), bool)
    first[:, ::12] = True
    stats = hand_made(gate, first)
    rows = stats.segments()
    assert rows[0] == [12, 12, 12, 12]
    assert float(stats.holding(gap)) == pytest.approx(null_holding_in(q, gap, rows), abs=0.02)
    assert null_holding_in(q, gap, rows) < null_holding(q, gap, 48) - 0.1
    assert null_holding_in(q, gap, [[48]]) == pytest.approx(null_holding(q, gap, 48))
    segments = [s for row in rows for s in row]
    runs = float(stats.closed_runs.sum())
    assert runs == pytest.approx(400 * 16 * expected_closed_runs(q, segments) / 400, rel=0.02)
    summary = stats.summary(gaps=[gap], memory_gap=6)
    null = geometric_null(q, int(runs), segments)
    assert summary["gates/closed_run_mean"] == pytest.approx(null["mean"], rel=0.02)
    assert null["mean"] < geometric_null(q, int(runs), 48)["mean"]
    assert summary["gates/null_run_max"] == null["max"] == 12  # capped at an episode
    assert summary[f"gates/null_holding_{gap}"] == pytest.approx(
        null_holding_in(summary["gates/open"], gap, rows))
    assert summary["gates/written_and_held_6"] == pytest.approx(
        null_written_and_held(q, 5), abs=0.01)
    assert summary["gates/null_written_and_held_6"] == pytest.approx(
        null_written_and_held(summary["gates/open"], 5))
    assert "gates/written_and_held_20" not in stats.summary(memory_gap=20)  # no episode fits
