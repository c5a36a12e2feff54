"""Every config value is checked when the config is built (vsgjax/config/checks.py)."""

import pytest

import bbs
from tests.support.registry_names import example_tasks
from vsgjax.config import (
    MODELS,
    SIZES,
    VECTOR_SIZES,
    ConfigError,
    default_config,
    make_config,
    settings_of,
)
from vsgjax.config.checks import (
    CHECKED_AT_START,
    RANGES,
    Range,
    max_episode_steps,
    numeric_values,
)
from vsgjax.registry.agents import agent_entry
from vsgjax.registry.tasks import VECTOR, family_of

TASKS = example_tasks()  # bbs, dmc, atari (images), mjx, gymnax (vectors, on the device)


def test_every_preset_is_valid():
    """Every model, task family and size that fit together resolve (DrQ-v2 acts in continuous
    action spaces only, DreamerPro and VSGPro read images only, the cpu size reads vectors
    only)."""
    resolved = 0
    for task in TASKS:
        family = family_of(task)
        for model in MODELS:
            for size in SIZES:
                entry = agent_entry(model)
                fits = family.actions in entry.actions and (
                    family.observations in entry.observations) and (
                    size not in VECTOR_SIZES or family.observations == VECTOR)
                if fits:
                    make_config(task, model, size)
                    resolved += 1
    # the 5 Dreamer models with a decoder: 5 tasks x 3 sizes, and cpu on the 2 vector tasks;
    # DrQ-v2: the 3 continuous tasks x 3 sizes and cpu on mjx; DreamerPro, VSGPro: 3 image tasks
    assert resolved == 5 * 5 * 3 + 5 * 2 + 3 * 3 + 1 + 2 * 3 * 3


def test_every_numeric_key_has_a_range():
    """Each agent's numeric keys have ranges (the shared ones' or its settings module's), and
    every range is of a key some agent has."""
    every_key, every_range = set(), set(RANGES)
    for model in MODELS:
        keys = set(numeric_values(default_config(model))) - set(CHECKED_AT_START)
        ranges = set(RANGES) | set(settings_of(model).RANGES)
        assert keys <= ranges, (model, sorted(keys - ranges))
        every_key |= keys
        every_range |= set(settings_of(model).RANGES)
    assert every_key == every_range


BAD_VALUES = {
    "train.steps=-5": "config key 'train.steps' got -5; valid: >= 1",
    "train.steps=0": "config key 'train.steps' got 0; valid: >= 1",
    "train.batch=0": "config key 'train.batch' got 0; valid: >= 1",
    "train.batch=-3": "config key 'train.batch' got -3; valid: >= 1",
    "train.eval_episodes=0": "config key 'train.eval_episodes' got 0; valid: >= 1",
    "train.prefill=-1": "config key 'train.prefill' got -1; valid: >= 0",
    "train.length=1": "config key 'train.length' got 1; valid: >= 2",
    "train.seed=-1": "config key 'train.seed' got -1; valid: [0, 1073741824]",
    "wm.lr=nan": "config key 'wm.lr' got nan, which is not a finite number; valid: > 0",
    "wm.gate_kappa=1": "config key 'wm.gate_kappa' got 1.0; valid: (0, 1)",
    "ac.gamma=1.5": "config key 'ac.gamma' got 1.5; valid: [0, 1]",
    "model.gate_bias=inf": ("config key 'model.gate_bias' got inf, which is not a finite number; "
                            "valid: any finite number"),
    "env.num_envs=0": "config key 'env.num_envs' got 0; valid: >= 1",
    "ac.horizon=1": "'ac.horizon' got 1 with ac.alignment=release, which imagines horizon - 1 "
                    "steps; valid: >= 2 (or ac.alignment=next_state)",
    "train.replay_capacity=5": "train.replay_capacity=5 holds no sequence of train.length=10 "
                               "steps; valid: >= 10",
    "env.sticky=0.25": "env.sticky=0.25 is an Atari option; valid for task 'bbs_basic': "
                       "env.sticky=0",
    "env.grayscale=true": "env.grayscale=True is an Atari option",
}


@pytest.mark.parametrize("override", BAD_VALUES)
def test_a_bad_value_is_an_error_naming_key_value_and_range(override):
    with pytest.raises(ConfigError) as error:
        make_config("bbs_basic", "vsg", "debug", [override])
    assert BAD_VALUES[override] in str(error.value)


def test_edges_of_the_ranges_are_valid():
    make_config("bbs_basic", "vsg", "debug", [
        "train.prefill=0", "train.pretrain=0", "train.length=2", "ac.horizon=1",
        "ac.alignment=next_state", "wm.mlp_layers=0", "ac.gamma=1", "train.replay_capacity=10"])
    make_config("atari_pong", "vsg", "debug", ["env.sticky=1"])


def test_a_sequence_longer_than_the_tasks_episodes_is_an_error():
    with pytest.raises(ConfigError) as error:
        make_config("bbs_basic", "vsg", "debug", ["env.time_limit=200", "train.length=300"])
    assert str(error.value) == (
        "train.length=300 is longer than an episode of bbs_basic can be (52 stored steps with "
        "env.time_limit=200 and env.action_repeat=4); valid: <= 52")
    make_config("bbs_basic", "vsg", "debug", ["env.time_limit=200", "train.length=52"])
    with pytest.raises(ConfigError, match=r"mjx_cartpole_swingup can be \(21 stored steps"):
        make_config("mjx_cartpole_swingup", "vsg", "debug",
                    ["env.time_limit=40", "train.length=22"])


def test_more_imagination_starts_than_an_update_has_is_an_error():
    with pytest.raises(ConfigError) as error:
        make_config("mjx_cheetah_run", "vsg", "cpu", ["ac.starts=513"])
    assert str(error.value) == (
        "config key 'ac.starts' got 513, more than the 512 posterior states of an update "
        "(train.batch=16 x train.length=32); valid: 0 (every one) to 512")
    make_config("mjx_cheetah_run", "vsg", "cpu", ["ac.starts=512"])
    # the release drops the last step of each sequence when there is a discount head
    with pytest.raises(ConfigError, match=r"the 36 posterior states .* minus its last step"):
        make_config("bbs_basic", "vsg", "debug", ["ac.starts=37"])
    make_config("bbs_basic", "vsg", "debug", ["ac.starts=36"])


def test_the_bbs_episode_bound_is_the_envs_own_length():
    config = make_config("bbs_basic", "vsg", "debug", ["env.time_limit=200"])
    env = bbs.make("bbs_basic", time_limit=200, action_repeat=4, obs_size=16)
    env.reset(seed=0)
    steps, done = 1, False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample() * 0)
        steps, done = steps + 1, terminated or truncated
    assert steps == max_episode_steps(config) == 52


def test_range_text():
    assert str(Range(0, 1, open_low=True)) == "(0, 1]"
    assert str(Range(0.5)) == ">= 0.5"
    assert 1.0 in Range(1) and 0.0 not in Range(0, open_low=True)

