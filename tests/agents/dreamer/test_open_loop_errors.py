"""The open-loop test as numbers (vsgjax/agents/dreamer/open_loop.py): the world model's
prediction error at each imagined step after observing the first steps of recorded episodes.

A fresh debug world model on vector observations (cheap to compile), and one on 64x64 images;
the episodes are random, and where the test needs a model that predicts exactly, the episode's
later steps are replaced by what the model itself imagines from its first steps.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from vsgjax.agents.dreamer import api
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.agents.dreamer.open_loop import (
    CONTEXT,
    HORIZON,
    open_loop_errors,
    shortened,
    shortened_open_loop_errors,
)
from vsgjax.agents.drqv2.agent import DrQV2Agent
from vsgjax.config import make_config

VECTOR_TASK, IMAGE_TASK = "mjx_cartpole_swingup", "dmc_walker_walk"
CONFIG = make_config(VECTOR_TASK, "vsg", "debug")
AGENT = DreamerAgent(CONFIG, {"vector": (5,)}, 1, False)


@pytest.fixture(scope="module")
def wm():
    return AGENT.init(jax.random.PRNGKey(0)).params["wm"]


def random_episodes(count: int, steps: int, seed: int = 0, image: bool = False) -> dict:
    """``count`` episodes of ``steps`` steps in the episode format (zero action and reward at
    the first step)."""
    rng = np.random.default_rng(seed)
    action = rng.uniform(-1, 1, (count, steps, 2 if image else 1)).astype(np.float32)
    action[:, 0] = 0
    reward = rng.normal(size=(count, steps)).astype(np.float32)
    reward[:, 0] = 0
    episodes = {"action": action, "reward": reward,
                "is_first": np.arange(steps)[None].repeat(count, 0) == 0,
                "is_terminal": np.zeros((count, steps), bool)}
    if image:
        episodes["image"] = rng.integers(0, 256, (count, steps, 64, 64, 3), dtype=np.uint8)
    else:
        episodes["vector"] = rng.normal(size=(count, steps, 5)).astype(np.float32)
    return episodes


def by_hand(config, wm, episodes: dict, key, context: int = CONTEXT, horizon: int = HORIZON):
    """The test spelled out with the public API: observe steps 0..context-1, imagine
    ``horizon`` steps under actions context..context+horizon-1 (keys split as documented)."""
    observe_key, imagine_key = jax.random.split(key)
    keys = [k for k in episodes if k != "is_terminal"]
    posts, _ = api.observe(config, wm, {k: episodes[k][:, :context] for k in keys}, observe_key)
    start = jax.tree.map(lambda x: x[:, -1], posts)
    return api.imagine(wm, start, horizon, config=config, key=imagine_key,
                       actions=episodes["action"][:, context:context + horizon])


def test_a_model_that_predicts_the_episode_exactly_has_no_error(wm):
    """Steps 15..49 of the episodes set to the model's own imagination from steps 0..14: zero
    error at every imagined step; one step off (the truth of step 16 + k - 1 compared at
    imagined step k) is not."""
    episodes, key = random_episodes(3, 50), jax.random.PRNGKey(1)
    imagined = by_hand(CONFIG, wm, episodes, key)
    exact = {k: v.copy() for k, v in episodes.items()}
    exact["vector"][:, CONTEXT:] = np.asarray(imagined["vectors"]["vector"])
    exact["reward"][:, CONTEXT:] = np.asarray(imagined["rewards"])
    errors = jax.device_get(open_loop_errors(CONFIG, wm, exact, key))
    assert errors["obs_mse"].shape == errors["reward_mse"].shape == (HORIZON,)
    np.testing.assert_allclose(errors["obs_mse"], 0, atol=1e-9)
    np.testing.assert_allclose(errors["reward_mse"], 0, atol=1e-9)
    late = {k: v.copy() for k, v in exact.items()}
    late["vector"][:, CONTEXT + 1:] = exact["vector"][:, CONTEXT:-1]
    late["reward"][:, CONTEXT + 1:] = exact["reward"][:, CONTEXT:-1]
    shifted = jax.device_get(open_loop_errors(CONFIG, wm, late, key))
    assert (shifted["obs_mse"][1:] > 1e-6).all() and (shifted["reward_mse"][1:] > 1e-9).all()


def test_the_error_at_each_step_is_the_mse_of_that_imagined_step(wm):
    """Against recorded (random) episodes: entry k - 1 is the MSE, over episodes and vector
    entries, of imagined step k against episode step 15 + k - 1; the reward's likewise."""
    episodes, key = random_episodes(3, 50, seed=2), jax.random.PRNGKey(3)
    imagined = jax.device_get(by_hand(CONFIG, wm, episodes, key))
    errors = jax.device_get(open_loop_errors(CONFIG, wm, episodes, key))
    truth = episodes["vector"][:, CONTEXT:]
    np.testing.assert_allclose(errors["obs_mse"],
                               ((imagined["vectors"]["vector"] - truth) ** 2).mean((0, 2)),
                               rtol=1e-4)
    np.testing.assert_allclose(errors["reward_mse"],
                               ((imagined["rewards"] - episodes["reward"][:, CONTEXT:]) ** 2
                                ).mean(0), rtol=1e-4)
    assert errors["obs_mse"][0] > 0.1  # random vectors of unit variance: far from predicted


def test_rewards_compare_in_the_heads_units_with_reward_tanh():
    config = make_config(VECTOR_TASK, "vsg", "debug", ["wm.reward_tanh=true"])
    agent = DreamerAgent(config, {"vector": (5,)}, 1, False)
    wm = agent.init(jax.random.PRNGKey(0)).params["wm"]
    episodes, key = random_episodes(3, 50, seed=4), jax.random.PRNGKey(5)
    episodes["reward"] *= 3
    imagined = jax.device_get(by_hand(config, wm, episodes, key))
    errors = jax.device_get(open_loop_errors(config, wm, episodes, key))
    target = np.tanh(episodes["reward"][:, CONTEXT:])
    np.testing.assert_allclose(errors["reward_mse"], ((imagined["rewards"] - target) ** 2).mean(0),
                               rtol=1e-4)


def test_images_compare_in_the_decoders_float_scale():
    """Pixels as uint8 / 255 - 0.5 (the MSE of pixels in [0, 1]): the model's own imagination
    rounded to uint8 is within rounding of zero, and the error of other pixels is the hand
    MSE."""
    config = make_config(IMAGE_TASK, "vsg", "debug")
    wm = api.init(config, jax.random.PRNGKey(0), (64, 64, 3), 2).params
    episodes, key = random_episodes(1, 8, seed=6, image=True), jax.random.PRNGKey(7)
    context, horizon = shortened(8)
    imagined = jax.device_get(by_hand(config, wm, episodes, key, context, horizon))
    errors = jax.device_get(open_loop_errors(config, wm, episodes, key, context, horizon))
    truth = episodes["image"][:, context:].astype(np.float32) / 255 - 0.5
    np.testing.assert_allclose(errors["obs_mse"],
                               ((imagined["image_means"] - truth) ** 2).mean((0, 2, 3, 4)),
                               rtol=1e-4)
    exact = dict(episodes, image=episodes["image"].copy())
    exact["image"][:, context:] = imagined["images"]
    errors = jax.device_get(open_loop_errors(config, wm, exact, key, context, horizon))
    assert errors["obs_mse"].shape == (horizon,)
    assert (errors["obs_mse"] <= (0.5 / 255) ** 2 * 1.01).all()


def test_short_episodes_shorten_context_and_horizon_in_the_15_to_35_ratio(wm):
    assert shortened(50) == shortened(80) == (15, 35)
    assert shortened(20) == (6, 14) and shortened(4) == (2, 2) and shortened(3) is None
    key = jax.random.PRNGKey(8)
    short = random_episodes(2, 20, seed=9)
    errors = jax.device_get(shortened_open_loop_errors(CONFIG, wm, short, key))
    assert errors["obs_mse"].shape == (14,)
    direct = jax.device_get(open_loop_errors(CONFIG, wm, short, key, 6, 14))
    np.testing.assert_array_equal(errors["obs_mse"], direct["obs_mse"])
    assert shortened_open_loop_errors(CONFIG, wm, random_episodes(2, 3), key) is None
    long = random_episodes(2, 80, seed=10)  # steps after the 50th are not read
    first_50 = {k: v[:, :50] for k, v in long.items()}
    np.testing.assert_array_equal(
        jax.device_get(shortened_open_loop_errors(CONFIG, wm, long, key))["obs_mse"],
        jax.device_get(open_loop_errors(CONFIG, wm, first_50, key))["obs_mse"])
    with pytest.raises(ValueError, match="shorter than context"):
        open_loop_errors(CONFIG, wm, short, key)


def test_the_agent_hook_is_jittable_and_only_agents_with_a_world_model_offer_it(wm):
    state = AGENT.init(jax.random.PRNGKey(0))
    episodes, key = random_episodes(2, 51, seed=11), jax.random.PRNGKey(12)
    eager = jax.device_get(AGENT.open_loop_errors(state, episodes, key))
    compiled = jax.device_get(jax.jit(AGENT.open_loop_errors)(state, episodes, key))
    assert eager["obs_mse"].shape == (HORIZON,)
    np.testing.assert_allclose(compiled["obs_mse"], eager["obs_mse"], rtol=1e-5)
    np.testing.assert_allclose(compiled["reward_mse"], eager["reward_mse"], rtol=1e-5)
    assert not hasattr(DrQV2Agent, "open_loop_errors")
