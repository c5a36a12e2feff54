"""The committed DreamerPro reference curves (experiments/reference_scores/dreamerpro_dmc.json, made
by convert_dreamerpro.py from fdeng18/dreamer-pro's plots/*/runs.json; provenance in that folder's
PROVENANCE.md): schema, record counts, task names, xs, method labels, and that the report loads it.
Needs only the committed file, not the source repository."""

import json
from collections import Counter
from itertools import pairwise

import pytest

from experiments.reference_scores import convert_dreamerpro
from experiments.report import REFERENCE_DIR, load_reference
from experiments.report.reference import merge_references
from experiments.spec import Run
from vsgjax.envs.dmc import all_tasks
from vsgjax.registry.agents import AGENTS, prototype_models

NAME = "dreamerpro_dmc.json"
PATH = REFERENCE_DIR / NAME
RECORDS = json.loads(PATH.read_text())
STANDARD_TASKS = {"dmc_ball_in_cup_catch", "dmc_cartpole_swingup_sparse", "dmc_cheetah_run",
                  "dmc_finger_spin", "dmc_reacher_easy", "dmc_walker_run"}
NATURAL_TASKS = STANDARD_TASKS - {"dmc_cartpole_swingup_sparse"} | {"dmc_cartpole_swingup"}
STANDARD_METHODS = ["DreamerPro", "DreamerV2 (DreamerPro repo)", "TPC"]
NATURAL_METHODS = ["DreamerPro-natural", "DreamerV2-natural (DreamerPro repo)", "TPC-natural"]


def test_schema_and_canonical_form():
    assert isinstance(RECORDS, list) and len(RECORDS) == 108
    for record in RECORDS:
        assert set(record) == {"task", "method", "seed", "xs", "ys"}
        assert isinstance(record["seed"], str)
        assert all(isinstance(x, int) for x in record["xs"])
        assert all(isinstance(y, (int, float)) and y == round(y, 1) for y in record["ys"])
    # the file is the converter's canonical output (one record a line, sorted)
    assert PATH.read_text() == convert_dreamerpro.dumps(RECORDS)


def test_record_counts_per_method():
    assert Counter(r["method"] for r in RECORDS) == {m: 18 for m in
                                                      STANDARD_METHODS + NATURAL_METHODS}
    assert list(convert_dreamerpro.METHODS.values()) == STANDARD_METHODS + NATURAL_METHODS
    per = Counter((r["task"], r["method"]) for r in RECORDS)
    assert per == {**{(t, m): 3 for t in STANDARD_TASKS for m in STANDARD_METHODS},
                   **{(t, m): 3 for t in NATURAL_TASKS for m in NATURAL_METHODS}}
    for task, method in per:
        seeds = [r["seed"] for r in RECORDS if (r["task"], r["method"]) == (task, method)]
        assert seeds == ["indir1_1", "indir1_2", "indir1_3"], (task, method)


def test_tasks_are_this_projects_dmc_tasks():
    valid = {f"dmc_{domain}_{task}" for domain, task in all_tasks()}
    tasks = {r["task"] for r in RECORDS}
    assert all(t.startswith("dmc_") for t in tasks)
    assert tasks <= valid, tasks - valid
    assert tasks == STANDARD_TASKS | NATURAL_TASKS  # cup_catch -> ball_in_cup_catch


def test_xs_are_increasing_env_steps():
    for record in RECORDS:
        xs, ys = record["xs"], record["ys"]
        assert len(xs) == len(ys) > 0
        assert all(b > a for a, b in pairwise(xs)), (record["task"], record["method"])
        # 10k-env-step bins (eval_every 1e4 env steps = 5k agent steps x action repeat 2)
        assert xs == list(range(10_000, 1_000_000, 10_000)), (record["task"], record["method"])


def test_the_report_loads_it():
    reference = load_reference(NAME)
    assert reference.spacing == 10_000
    assert len(reference.curves) == 36
    assert len(reference.seeds("dmc_walker_run", "DreamerPro-natural")) == 3
    assert reference.paper_names[("dmc_ball_in_cup_catch", "DreamerPro")] == (
        "dmc_ball_in_cup_catch", "DreamerPro")
    # beside the other DMC reference files: no (task, method) is drawn twice
    merged = merge_references([load_reference("vsg_paper_dmc.json"),
                               load_reference("drqv2_dmc.json"), reference])
    assert ("dmc_walker_run", "DreamerV2") in merged.curves  # the VSG paper's, not DreamerPro's
    assert len(merged.seeds("dmc_walker_run", "DreamerV2 (DreamerPro repo)")) == 3


def test_labels_against_our_run_labels():
    reference = load_reference(NAME)
    methods = {method for _, method in reference.curves}
    # our DreamerV2 runs (plain and with the natural-background variant) get no DreamerPro-repo
    # curve as "their paper curve": that DreamerV2 is another configuration
    for variant in ("", "natural"):
        label = Run("x", "dmc_walker_run", "dreamerv2", 0, variant=variant).method
        assert label in ("DreamerV2", "DreamerV2-natural") and label not in methods
    # our DreamerPro runs, once the model exists, match the authors' curves by label
    if "dreamerpro" in AGENTS:
        for variant in ("", "natural"):
            assert Run("x", "dmc_walker_run", "dreamerpro", 0, variant=variant).method in methods


def test_converter_names_and_checks():
    assert convert_dreamerpro.project_task("nat_cup_catch") == "dmc_ball_in_cup_catch"
    assert convert_dreamerpro.project_task("dmc_cup_catch") == "dmc_ball_in_cup_catch"
    assert (convert_dreamerpro.project_task("dmc_cartpole_swingup_sparse")
            == "dmc_cartpole_swingup_sparse")
    assert convert_dreamerpro.project_task("nat_walker_run") == "dmc_walker_run"
    source = json.dumps([
        {"task": "nat_cup_catch", "method": "dreamerv2_32", "seed": "indir1_2",
         "xs": [10000.0, 20000.0], "ys": [90.27272727, 286.25]},
        {"task": "nat_cup_catch", "method": "dreamer_pro_v2_freeze_10k", "seed": "indir1_1",
         "xs": [10000.0], "ys": [3.0]}]).encode()
    records = convert_dreamerpro.records_of(convert_dreamerpro.NATURAL, source)
    assert records == [
        {"task": "dmc_ball_in_cup_catch", "method": "DreamerV2-natural (DreamerPro repo)",
         "seed": "indir1_2", "xs": [10000, 20000], "ys": [90.3, 286.2]},
        {"task": "dmc_ball_in_cup_catch", "method": "DreamerPro-natural", "seed": "indir1_1",
         "xs": [10000], "ys": [3.0]}]
    # a natural-background method in the standard file, or xs that go back, are refused
    with pytest.raises(convert_dreamerpro.ConversionError):
        convert_dreamerpro.records_of(convert_dreamerpro.STANDARD, source)
    bad = json.dumps([{"task": "nat_cup_catch", "method": "dreamerv2_32", "seed": "indir1_1",
                       "xs": [20000.0, 10000.0], "ys": [1.0, 2.0]}]).encode()
    with pytest.raises(convert_dreamerpro.ConversionError):
        convert_dreamerpro.records_of(convert_dreamerpro.NATURAL, bad)
    with pytest.raises(convert_dreamerpro.ConversionError):
        convert_dreamerpro.check_sources({convert_dreamerpro.STANDARD: b"[]"})


def test_two_final_returns_in_provenance():
    def final_mean(task: str, method: str) -> float:
        ends = [r["ys"][-1] for r in RECORDS if (r["task"], r["method"]) == (task, method)]
        return sum(ends) / len(ends)

    assert final_mean("dmc_walker_run", "DreamerPro") == pytest.approx(783.6, abs=0.05)
    assert final_mean("dmc_cheetah_run", "DreamerPro-natural") == pytest.approx(349.1, abs=0.05)


def test_the_natural_dmc_experiment_resolves_and_meets_the_authors_curves():
    """experiments/paper/natural_dmc.toml: 6 tasks x 4 models x 3 seeds at 500k env steps,
    every run's config resolves, and DreamerPro's natural-background curve shares its label
    with our DreamerPro runs (so the curves figure draws the two side by side)."""
    from experiments.spec import load_experiment
    from vsgjax.config import make_config

    experiment = load_experiment("natural_dmc")
    assert len(experiment.runs) == 6 * 4 * 3
    assert {run.steps for run in experiment.runs} == {500_000}
    for run in experiment.runs:
        config = make_config(run.task, run.model, run.size, run.config_overrides)
        assert config.env.background == "video"
        assert config.wm.reward_scale == (1000.0 if run.model in prototype_models()
                                          else 2.0)
    ours = {(run.task, run.method) for run in experiment.runs}
    theirs = {(r["task"], r["method"]) for r in RECORDS}
    assert {method for _, method in ours & theirs} == {"DreamerPro-natural"}
    assert {task for task, _ in ours & theirs} == NATURAL_TASKS
