"""Config presets (spec section 5) and error messages for bad names, keys and types."""

import dataclasses
import json
import pickle
import re
from pathlib import Path

import pytest

from tests.support.doc_tables import cell_value, config_value, table_rows
from tests.support.registry_names import example_tasks, one_model_per_agent
from vsgjax.config import (
    MODELS,
    SIZES,
    ConfigError,
    apply_overrides,
    config_changes,
    from_dict,
    make_config,
    to_dict,
)
from vsgjax.config.presets import preset_layers
from vsgjax.config.schema import DOTTED_FIELDS
from vsgjax.registry.agents import agent_entry, dreamer_models, prototype_models
from vsgjax.registry.tasks import CONTINUOUS, DISCRETE, FAMILIES, IMAGE, VECTOR, family_of


@pytest.mark.parametrize(
    "call, named, listed",
    [
        (lambda: make_config(model="vsgg"), "'vsgg'", MODELS),
        (lambda: make_config(size="huge"), "'huge'", SIZES),
        (lambda: make_config(overrides=["wm.kl_scael=0.3"]), "'wm.kl_scael'", ("kl_scale",)),
        (lambda: make_config(overrides=["optimizer.lr=0.3"]), "'optimizer.lr'",
         ("model", "wm", "ac", "optim")),
        (lambda: make_config(overrides=["optim.lr=0.3"]), "'optim.lr'", ("weight_decay",)),
        (lambda: make_config(overrides=["ac.alignment=dreamerv3"]), "'dreamerv3'",
         ("release", "next_state")),
        (lambda: make_config(overrides=["optim.weight_decay=l2"]), "'l2'", ("release", "adamw")),
        (lambda: make_config(overrides=["optim.eps_placement=inside"]), "'inside'",
         ("release", "optax")),
        (lambda: make_config(overrides=["wm.kl_scale=abc"]), "'abc'", ("float",)),
        (lambda: make_config(overrides=["model.deter=1.5"]), "'1.5'", ("int",)),
        (lambda: make_config(overrides=["wm.kl_masked=maybe"]), "'maybe'", ("bool",)),
        (lambda: make_config(task="mujoco_cheetah"), "'mujoco_cheetah'",
         tuple(f"{prefix}_" for prefix in FAMILIES)),
        # the task picks the presets: an override would leave them another task's
        (lambda: make_config(overrides=["env.task=mjx_cartpole_swingup"]), "'env.task'",
         ("--task",)),
    ],
)
def test_errors_name_the_bad_value_and_list_valid_ones(call, named, listed):
    with pytest.raises(ConfigError) as info:
        call()
    message = str(info.value)
    assert named in message
    for valid in listed:
        assert valid in message


def test_missing_equals_sign_is_an_error():
    with pytest.raises(ConfigError, match="section.key=value"):
        make_config(overrides=["wm.kl_scale"])


def test_overrides_are_typed():
    config = make_config(overrides=["wm.kl_scale=0.3", "model.deter=512", "wm.kl_masked=true",
                                    "train.steps=1_000_000", "model.gate_mode=threshold"])
    assert config.wm.kl_scale == 0.3
    assert config.model.deter == 512
    assert config.wm.kl_masked is True
    assert config.train.steps == 1_000_000 and isinstance(config.train.steps, int)
    assert config.model.gate_mode == "threshold"


def test_overrides_apply_on_top_of_presets():
    base = make_config("dmc_walker_walk", "vsg", "paper")
    changed = apply_overrides(base, ["wm.gate_kappa=0.5"])
    assert changed.wm.gate_kappa == 0.5
    assert dataclasses.replace(changed, wm=base.wm) == base


BBS_PAPER = {
    "env.action_repeat": 4, "env.time_limit": 3000, "train.batch": 16, "train.length": 50,
    "model.deter": 1024, "model.hidden": 1024, "model.stoch": 32, "model.classes": 32,
    "wm.cnn_depth": 48, "wm.mlp_layers": 4, "wm.mlp_units": 400,
    "wm.kl_scale": 1.0, "wm.kl_balance": 0.8, "wm.kl_free": 0.0,
    "wm.gate_alpha": 0.1, "wm.gate_kappa": 0.3, "wm.gate_free": 0.1,
    "wm.lr": 1e-4, "ac.actor_lr": 8e-5, "ac.critic_lr": 2e-4,
    "wm.discount_head": True, "wm.discount_scale": 1.0, "wm.reward_scale": 1.0,
    "ac.gamma": 0.99, "ac.lam": 0.95, "ac.horizon": 15, "ac.entropy": 2e-3,
    "wm.eps": 1e-5, "wm.clip": 100.0, "wm.weight_decay": 1e-6,
    "train.train_every": 5, "train.prefill": 10_000, "ac.slow_critic_every": 100,
    "train.steps": 2_500_000,
}
DMC_PAPER = {
    "env.action_repeat": 2, "env.time_limit": 1000, "train.batch": 50, "train.length": 50,
    "model.deter": 1024, "model.hidden": 1024, "wm.cnn_depth": 32,
    "wm.reward_layers": 2, "ac.critic_layers": 3, "ac.actor_layers": 4, "wm.mlp_units": 400,
    "wm.kl_scale": 1.0, "wm.kl_balance": 0.8, "wm.kl_free": 1.0,
    "wm.gate_alpha": 0.1, "wm.gate_kappa": 0.4, "wm.gate_free": 0.1,
    "wm.lr": 3e-4, "ac.actor_lr": 8e-5, "ac.critic_lr": 8e-5,
    "wm.discount_head": False, "wm.reward_scale": 2.0, "ac.gamma": 0.99, "ac.entropy": 1e-4,
    "wm.weight_decay": 0.0, "train.train_every": 5, "train.prefill": 2500,
    "train.steps": 1_000_000,
}
ATARI_PAPER = {
    "env.action_repeat": 4, "env.time_limit": 108_000, "env.grayscale": True, "env.sticky": 0.25,
    "train.batch": 16, "train.length": 50, "model.deter": 600, "model.hidden": 600,
    "model.stoch": 32, "model.classes": 32, "wm.cnn_depth": 48, "wm.mlp_layers": 4,
    "wm.mlp_units": 400, "wm.kl_scale": 0.1, "wm.kl_balance": 0.8, "wm.kl_free": 0.0,
    "wm.gate_kappa": 0.4, "wm.lr": 2e-4, "ac.actor_lr": 4e-5, "ac.critic_lr": 1e-4,
    "wm.discount_head": True, "wm.discount_scale": 5.0, "wm.reward_tanh": True,
    "ac.gamma": 0.999, "ac.entropy": 1e-3, "ac.actor_grad": "reinforce",
    "train.train_every": 16, "train.prefill": 200_000, "train.steps": 200_000_000,
}


@pytest.mark.parametrize("task, table", [("bbs_basic", BBS_PAPER), ("dmc_walker_walk", DMC_PAPER),
                                         ("atari_pong", ATARI_PAPER)])
def test_paper_presets_match_the_spec_table(task, table):
    config = make_config(task, "vsg", "paper")
    wrong = {key: (config_value(config, key), want) for key, want in table.items()
             if config_value(config, key) != want}
    assert not wrong


def test_svsg_presets():
    bbs = make_config("bbs_basic", "svsg", "paper")
    assert (bbs.model.deter, bbs.model.stoch, bbs.model.classes) == (0, 1024, 0)
    assert bbs.wm.kl_masked and bbs.wm.kl_free == 1.0 and not bbs.model.cell_norm
    assert make_config("dmc_walker_walk", "svsg", "paper").wm.kl_free == 1.0


def test_baselines_use_layernorm_gru_and_vsg_does_not():
    assert make_config(model="dreamerv2").model.cell_norm
    assert make_config(model="dreamerv1").model.cell_norm
    assert not make_config(model="vsg").model.cell_norm
    assert make_config(model="dreamerv1").model.classes == 0


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("size", SIZES)
def test_every_preset_resolves_and_round_trips(model, size):
    if size == "cpu" and VECTOR not in agent_entry(model).observations:
        with pytest.raises(ConfigError, match="reads image observations"):
            make_config("mjx_walker_walk", model, size)  # the cpu size is for vector tasks only
        return
    config = make_config("mjx_walker_walk" if size == "cpu" else "bbs_basic", model, size)
    assert config.agent == model and config.size == size
    assert from_dict(to_dict(config)) == config
    hash(config)


def test_sizes_shrink_the_networks():
    paper, small, debug = (make_config("bbs_basic", "vsg", s) for s in ("paper", "small", "debug"))
    assert paper.model.deter > small.model.deter > debug.model.deter
    assert paper.wm.cnn_depth > small.wm.cnn_depth > debug.wm.cnn_depth


@pytest.mark.parametrize("task", example_tasks(IMAGE))
def test_the_cpu_size_refuses_image_tasks_naming_size_task_and_what_is_valid(task):
    with pytest.raises(ConfigError) as error:
        make_config(task, "vsg", "cpu")
    message = str(error.value)
    assert "'cpu'" in message and repr(task) in message and "mjx_<domain>_<task>" in message
    assert "paper, small, debug" in message


def test_the_cpu_size_trains_vector_tasks_with_the_mlp_encoder():
    config = make_config("mjx_cheetah_run", "vsg", "cpu")
    assert (config.model.deter, config.wm.mlp_units, config.train.steps) == (128, 128, 100_000)
    assert config.wm.encoder == "auto" and config.ac.horizon == 15  # the release's horizon


def test_from_dict_rejects_unknown_keys():
    data = to_dict(make_config())
    data["wm"]["bogus"] = 1
    with pytest.raises(ConfigError, match="bogus"):
        from_dict(data)


# --- the saved form and its versions (vsgjax/config/saved.py) --------------------------------

OLD_DRQV2 = (Path(__file__).resolve().parent / "fixtures" / "rundir_v1"
             / "mjx_cartpole_swingup-drqv2-debug" / "config.json")


def test_a_saved_config_holds_only_what_its_agent_reads():
    drqv2 = to_dict(make_config("mjx_cartpole_swingup", "drqv2", "debug"))
    assert set(drqv2) == {"version", "agent", "domain", "size", "precision", "drq", "env",
                          "train"}
    assert drqv2["version"] == 2 and drqv2["agent"] == "drqv2"
    vsg = to_dict(make_config("mjx_cartpole_swingup", "vsg", "debug"))
    assert {k for k, v in vsg.items() if isinstance(v, dict)} == {
        "model", "wm", "ac", "optim", "env", "train"}
    assert "name" not in vsg["model"] and "precision" not in vsg["model"]


def test_a_version_1_config_migrates_to_what_its_agent_reads():
    """Version 1 held every agent's sections and the agent's name in ``model.name``."""
    old = json.loads(OLD_DRQV2.read_text())
    assert "version" not in old and old["model"]["name"] == "drqv2" and "wm" in old
    config = from_dict(old)
    assert config.agent == "drqv2" and not hasattr(config, "model")
    assert config.drq.hidden == old["drq"]["hidden"] and config.env.time_limit == 40
    assert config_changes(old, to_dict(config)) == []
    assert from_dict(to_dict(config)) == config


def test_a_saved_config_of_an_unknown_version_names_it():
    data = {**to_dict(make_config()), "version": 7}
    with pytest.raises(ConfigError, match="format version 7 cannot be migrated"):
        from_dict(data)
    old = json.loads(OLD_DRQV2.read_text())
    del old["model"]["name"]
    with pytest.raises(ConfigError, match="version 1 without model.name cannot be migrated"):
        from_dict(old)


def test_a_section_the_agent_does_not_read_is_refused_naming_its_readers():
    with pytest.raises(ConfigError, match="'wm.lr' is not read by model 'drqv2' .*read by "
                                          "dreamerv1, dreamerv2, vsg"):
        make_config("mjx_cartpole_swingup", "drqv2", "debug", ["wm.lr=0.1"])
    data = {**to_dict(make_config("mjx_cartpole_swingup", "drqv2", "debug")), "wm": {"lr": 0.1}}
    with pytest.raises(ConfigError, match="'wm'.*not read by model 'drqv2'"):
        from_dict(data)


def test_model_precision_sets_the_precision_of_every_agent():
    for model in one_model_per_agent():
        config = make_config("mjx_cartpole_swingup", model, "debug", ["model.precision=bfloat16"])
        assert config.precision == "bfloat16"


def test_a_task_family_without_the_agents_presets_is_refused():
    """An agent's presets hold only the columns it trains on; make_config's
    :func:`vsgjax.config.presets.check_agent_fits` refuses the others first, and the presets'
    lookup names the column should an entry claim a family its presets lack."""
    pretend = dataclasses.replace(agent_entry("drqv2"), actions=(CONTINUOUS, DISCRETE))
    with pytest.raises(ConfigError, match="'drqv2' .* no presets for the 'atari' column .* "
                                          "dmc, bbs"):
        preset_layers(pretend, family_of("atari_pong"), "atari_pong", "debug")


# --- the presets page's tables (docs/presets.md) ----------------------------------------------

PRESETS_PAGE = Path(__file__).resolve().parents[1] / "docs" / "presets.md"
TABLE_HEADER = "| key | BBS | DMC | Atari | source |"
CPU_HEADING = "## The `cpu` size (vector observations, `mjx_*` tasks)"
DOMAIN_TASKS = {"BBS": "bbs_basic", "DMC": "dmc_walker_walk", "Atari": "atari_pong"}
IDENTITY_KEYS = {"env.task", "train.seed"}  # the run's name, not a preset
# the page's tables are the Dreamer family's; DreamerPro's and VSGPro's is docs/dreamerpro.md's
DREAMER_MODELS = tuple(m for m in dreamer_models() if m not in prototype_models())


def _parse_cell(cell: str) -> dict:
    """``"a; m1 b; m2 c"`` -> {model: value} for every model of the Dreamer family."""
    default, *exceptions = [part.strip() for part in cell.split(";")]
    values = dict.fromkeys(DREAMER_MODELS, cell_value(default))
    for exception in exceptions:
        model, value = exception.split(" ", 1)
        assert model in DREAMER_MODELS, f"unknown model {model!r} in cell {cell!r}"
        values[model] = cell_value(value)
    return values


def page_presets() -> dict:
    """{key: {domain: {model: value}}} from the presets page's `paper` table."""
    return {key.strip("`"): {domain: _parse_cell(cell)
                             for domain, cell in zip(DOMAIN_TASKS, cells, strict=True)}
            for key, *cells, _source in table_rows(PRESETS_PAGE.read_text(), TABLE_HEADER)}


def test_presets_page_table_matches_make_config_cell_by_cell():
    table = page_presets()
    configs = {(domain, model): make_config(task, model, "paper")
               for domain, task in DOMAIN_TASKS.items() for model in DREAMER_MODELS}
    wrong = [f"{key} {domain} {model}: page {want!r}, make_config {got!r}"
             for key, domains in table.items() for domain, models in domains.items()
             for model, want in models.items()
             for got in [config_value(configs[domain, model], key)]
             if got != want or type(got) is not type(want)]
    assert not wrong, "\n".join(wrong)


def test_presets_page_table_lists_every_config_key_the_dreamer_family_reads():
    from vsgjax.registry.agents import AGENTS

    sections = {AGENTS[model].sections for model in DREAMER_MODELS}
    assert len(sections) == 1, f"the Dreamer models read different sections: {sections}"
    data = to_dict(make_config())
    keys = {f"{section}.{name}" for section, values in data.items() if isinstance(values, dict)
            for name in values}
    assert (keys | set(DOTTED_FIELDS)) - IDENTITY_KEYS == set(page_presets())


def test_a_saved_config_that_predates_a_key_counts_it_as_its_default():
    current = to_dict(make_config("bbs_basic", "vsg", "small"))
    saved = json.loads(json.dumps(current))
    del saved["wm"]["encoder"]
    assert config_changes(saved, current) == []
    changed = to_dict(make_config("bbs_basic", "vsg", "small", ["model.precision=bfloat16"]))
    assert config_changes(saved, changed) == ["precision: 'float32' -> 'bfloat16'"]


def test_presets_page_cpu_table_names_every_key_the_cpu_size_sets():
    from vsgjax.agents.dreamer.presets import SIZE
    from vsgjax.registry.agents import AGENTS

    named = {name for key, *_ in table_rows(PRESETS_PAGE.read_text(), "| key |", CPU_HEADING)
             for name in re.findall(r"`([a-z]+\.[a-z_]+)`", key)}
    sets = set(SIZE["cpu"]) | {key for model in DREAMER_MODELS
                               for key in AGENTS[model].by_size.get("cpu", {})}
    assert named == sets


def test_a_config_pickles_to_an_equal_config_of_its_agents_class():
    """The agents' config classes are built at run time; a pickle rebuilds them by name."""
    for model in MODELS:
        config = make_config("dmc_walker_walk", model, "debug", ["train.seed=3"])
        copy = pickle.loads(pickle.dumps(config))
        assert copy == config and type(copy) is type(config) and hash(copy) == hash(config)
