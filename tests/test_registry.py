"""The agent and task-family registries are the only places that name models and families.

Every string literal in ``vsgjax/`` and ``experiments/`` (parsed with ``ast``: plain strings
and the literal parts of f-strings) is checked: none may be a model name, a family prefix
(``"mjx"``), a prefix with its underscore (``"mjx_"``) or a whole task name (``"bbs_basic"``),
outside the registries themselves and the modules they point at (each agent's presets, each
family's env module). Outside the check: ``experiments/bench/`` (a benchmark's choice of
which model to time is data, as an experiment file's is) and ``experiments/reference_scores/``
(its converters read other projects' file names).

The tests may name the model or the task they are about, but not a list of several models or
of several families' tasks: those they take from the registries, by property
(``tests/support/registry_names.py``), so that no list of "all the models" goes stale.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from vsgjax.config import ConfigError, make_config
from vsgjax.envs import parse_task
from vsgjax.registry.agents import AGENTS, MODELS, agent_entry, dreamer_models, gated_models
from vsgjax.registry.tasks import FAMILIES, TaskError, family_of

ROOT = Path(__file__).resolve().parents[1]
SELF = Path(__file__).resolve().relative_to(ROOT).as_posix()
CHECKED = ("vsgjax", "experiments")
# besides the registries: the MJX task modules, and the scripts that pick the tasks they time
# (benchmarks), draw (documentation figures) or convert (reference scores)
EXEMPT_DIRS = ("vsgjax/registry", "vsgjax/envs/mjx", "experiments/bench", "experiments/figures",
               "experiments/reference_scores",
               "experiments/recall_probe.py")  # its default sweep is data, as a benchmark's is


def _module_path(reference: str) -> str:
    return reference.partition(":")[0].replace(".", "/") + ".py"


def exempt_files() -> set[str]:
    """The registries and the modules their entries name (presets, family env modules)."""
    files = {_module_path(entry.presets) for entry in AGENTS.values()}
    for family in FAMILIES.values():
        files |= {_module_path(family.parse), _module_path(family.build)}
    return files


def forbidden(text: str) -> bool:
    if text in MODELS or text in FAMILIES or text in {f"{p}_" for p in FAMILIES}:
        return True
    try:
        family_of(text)
    except TaskError:
        return False
    return text.count(" ") == 0 and text.islower() and text.replace("_", "").isalnum()


def literals(path: Path):
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            yield node.lineno, node.value


def test_no_model_or_family_name_outside_the_registries():
    exempt = exempt_files()
    found = []
    for top in CHECKED:
        for path in sorted((ROOT / top).rglob("*.py")):
            relative = path.relative_to(ROOT).as_posix()
            if relative in exempt or relative.startswith(EXEMPT_DIRS):
                continue
            found += [f"{relative}:{line}: {text!r}" for line, text in literals(path)
                      if forbidden(text)]
    assert not found, "names that belong in vsgjax/registry/:\n" + "\n".join(found)


# lists of named models in tests that are deliberate choices, not "all" or "every ... model"
CHOSEN_LISTS = {
    # the paper's model and its baseline: the fast cases; the other models' are marked slow
    ("tests/agents/dreamer/test_precision.py", ("vsg", "dreamerv2")),
    # the same pair trained end to end on the device (each a slow test)
    ("tests/loop/test_gymnax_device_loop.py", ("vsg", "dreamerv2")),
}


def name_lists(path: Path):
    """(line, names) of each list, tuple or set literal in ``path`` holding two or more
    model names, or task names or family prefixes of two or more families (``pytest.param``'s
    first argument counts; a tuple unpacked into names is separate choices, not a list)."""
    tree = ast.parse(path.read_text(), str(path))
    unpacked = {id(node.value) for node in ast.walk(tree) if isinstance(node, ast.Assign)
                and isinstance(node.targets[0], ast.Tuple)}
    for node in ast.walk(tree):
        if not isinstance(node, ast.List | ast.Tuple | ast.Set) or id(node) in unpacked:
            continue
        items = [item.args[0] if isinstance(item, ast.Call) and item.args else item
                 for item in node.elts]
        texts = [item.value for item in items if isinstance(item, ast.Constant)
                 and isinstance(item.value, str) and forbidden(item.value)]
        models = tuple(dict.fromkeys(t for t in texts if t in MODELS))
        families = {t.rstrip("_") if t.rstrip("_") in FAMILIES else family_of(t).prefix
                    for t in texts if t not in MODELS}
        if len(models) > 1 or len(families) > 1:
            yield node.lineno, models or tuple(texts)


def test_no_list_of_models_or_families_in_the_tests():
    found = []
    for path in sorted((ROOT / "tests").rglob("*.py")):
        relative = path.relative_to(ROOT).as_posix()
        if relative in (SELF, "tests/support/registry_names.py"):  # examples; the source
            continue
        found += [f"{relative}:{line}: {names}" for line, names in name_lists(path)
                  if (relative, names) not in CHOSEN_LISTS]
    assert not found, ("lists of names to take from the registries "
                       "(tests/support/registry_names.py):\n" + "\n".join(found))


def test_the_list_check_catches_a_list_of_models_and_one_of_families(tmp_path):
    module = tmp_path / "test_bad.py"
    module.write_text('MODELS = ("vsg", "svsg")\nTASKS = ["bbs_basic", pytest.param("mjx")]\n'
                      'ONE = ["vsg"]\nTASK, OTHER = "dmc_walker_walk", "atari_pong"\n')
    assert list(name_lists(module)) == [(1, ("vsg", "svsg")), (2, ("bbs_basic", "mjx"))]


def test_the_check_catches_a_literal_model_name(tmp_path):
    """The scan above can fail: a module with a model name and an f-string family prefix."""
    module = tmp_path / "bad.py"
    module.write_text('MODEL = "vsg"\nname = f"mjx_{1}"\nok = "vsgjax"\n')
    assert [text for _, text in literals(module) if forbidden(text)] == ["vsg", "mjx_"]


def test_every_entry_resolves_and_names_real_code():
    from vsgjax.config import settings_of
    from vsgjax.registry import resolve

    for entry in AGENTS.values():
        assert callable(resolve(entry.implementation)), entry.name
        assert (ROOT / _module_path(entry.presets)).exists(), entry.presets
        assert set(entry.sections) <= set(settings_of(entry.name).SECTIONS), entry.settings
    for family in FAMILIES.values():
        assert callable(resolve(family.parse)) and callable(resolve(family.build))
    assert set(gated_models()) < set(dreamer_models()) < set(MODELS)


def test_an_unknown_model_lists_the_registered_ones():
    with pytest.raises(ValueError, match="unknown model 'dreamerv4' .*; valid: dreamerv1"):
        agent_entry("dreamerv4")
    with pytest.raises(ConfigError, match="drqv2"):
        make_config("bbs_basic", "dreamerv4", "debug")


@pytest.mark.parametrize("kind, call, hint", [
    ("model", lambda: agent_entry("vgs"), "(did you mean 'vsg'?)"),
    ("model", lambda: make_config("bbs_basic", "dreamer_v2", "debug"),
     "(did you mean 'dreamerv2'?)"),
    ("family", lambda: make_config("dcm_walker_walk", "vsg", "debug"),
     "(did you mean 'dmc_walker_walk'?)"),
    ("task", lambda: parse_task("mjx_cartpole_swingpu"), "(did you mean 'mjx_cartpole_swingup'?)"),
    ("task", lambda: parse_task("dmc_walker_wlak"), "(did you mean 'dmc_walker_walk'?)"),
    ("task", lambda: parse_task("bbs_basik"), "(did you mean 'bbs_basic'?)"),
    ("key", lambda: make_config("bbs_basic", "vsg", "debug", ["wm.kl_scal=1"]),
     "(did you mean 'wm.kl_scale'?)"),
    ("section", lambda: make_config("bbs_basic", "vsg", "debug", ["w.kl_scale=1"]),
     "(did you mean 'wm.kl_scale'?)"),
])
def test_a_misspelt_name_gets_a_did_you_mean(kind, call, hint):
    with pytest.raises(ValueError) as error:
        call()
    assert hint in str(error.value)


@pytest.mark.parametrize("call", [lambda: agent_entry("transformer"),
                                  lambda: make_config("foo_walker_walk", "vsg", "debug"),
                                  lambda: parse_task("mjx_humanoid_run")])
def test_a_name_far_from_every_valid_one_gets_no_guess(call):
    with pytest.raises(ValueError) as error:
        call()
    assert "did you mean" not in str(error.value)


def test_a_discrete_task_refuses_a_continuous_only_agent_naming_model_task_and_why():
    with pytest.raises(ConfigError) as error:
        make_config("atari_pong", "drqv2", "debug")
    message = str(error.value)
    assert "'drqv2'" in message and "'atari_pong'" in message and "discrete" in message
    assert "valid models for 'atari_pong'" in message and "drqv2," not in message


@pytest.mark.parametrize("model, key, other", [
    ("drqv2", "wm.lr=1e-3", "drq.*"), ("drqv2", "ac.entropy=0.1", "drq.*"),
    ("vsg", "drq.nstep=1", "wm.*")])
def test_a_key_of_another_agent_is_refused_naming_the_key_and_the_model(model, key, other):
    with pytest.raises(ConfigError) as error:
        make_config("dmc_walker_walk", model, "debug", [key])
    message = str(error.value)
    assert repr(key.partition("=")[0]) in message and repr(model) in message and other in message
