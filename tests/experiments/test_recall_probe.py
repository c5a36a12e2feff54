"""Tests of ``python -m experiments.recall_probe`` at the debug size: L = 3, two updates, a
few held-out episodes (one compilation, shared by the module's tests)."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import pytest

from experiments import recall_probe
from experiments.recall_probe import Variant
from vsgjax.config import ConfigError
from vsgjax.envs.gymnax_tasks import OBS_KEY, MemoryChainTask

LENGTH, UPDATES, EPISODES, SIZE = 3, 2, 8, "debug"
GATED = Variant("vsg", "rate")


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("probe")
    records = recall_probe.sweep([LENGTH], [GATED], [0], UPDATES, EPISODES, out, SIZE)
    return out, records


def test_collected_episodes_align_the_final_reward_with_its_action():
    """Step L + 1's reward is +1 exactly when the action stored with it is the cue's bit
    (context = 2·bit - 1 at step 0), and 0 at every other step."""
    batch = recall_probe.collect(MemoryChainTask(LENGTH), jax.random.PRNGKey(3), 64)
    assert batch[OBS_KEY].shape == (64, LENGTH + 2, 3)
    assert batch["action"].shape == (64, LENGTH + 2, 2)
    bit = batch[OBS_KEY][:, 0, 2] > 0
    assert bool(jnp.all(batch[OBS_KEY][:, 1, 2] == batch[OBS_KEY][:, 0, 2]))  # shown twice
    assert bool(jnp.all(batch[OBS_KEY][:, 2:, 2] == 0))
    expected = jnp.where(jnp.argmax(batch["action"][:, -1], -1) == bit, 1.0, -1.0)
    assert bool(jnp.all(batch["reward"][:, -1] == expected))
    assert 0 < float((expected > 0).mean()) < 1  # both signs occur
    assert bool(jnp.all(batch["reward"][:, :-1] == 0))
    assert batch["is_first"][:, 0].all() and not batch["is_first"][:, 1:].any()
    assert batch["is_terminal"][:, -1].all() and not batch["is_terminal"][:, :-1].any()


def test_record_fields_and_ranges(swept):
    out, (record,) = swept
    assert record_on_disk(out) == record
    assert record["memory_length"] == LENGTH and record["variant"] == "vsg:rate"
    assert record["gate_objective"] == "rate" and record["sequence_length"] == LENGTH + 2
    for key in ("accuracy_filtered", "accuracy_open_loop"):
        assert 0.0 <= record[key] <= 1.0
        assert record[key] * EPISODES == round(record[key] * EPISODES)  # a count of episodes
    gates = record["gates"]
    assert 0.0 < gates["open"] < 1.0 and gates["gap"] == LENGTH - 1
    assert 0.0 <= gates["holding"] <= 1.0 and 0.0 <= gates["null_holding"] <= 1.0
    assert 1 <= gates["closed_run_mean"] <= gates["closed_run_max"] <= LENGTH + 2
    assert 0.0 < gates["prob_step1"] < 1.0 and 0.0 < gates["prob_other"] < 1.0
    assert 0.0 < gates["live_units"] <= 1.0 and gates["open"] <= gates["open_live"] + 1e-6 < 1.0
    # held live units are a part of all held units (the dead ones count as held there)
    assert 0.0 <= gates["live_holding"] * gates["live_units"] <= gates["holding"] + 1e-6
    # written at steps 1-2 and closed to the end: a part of the units closed across the gap
    assert 0.0 <= gates["written_and_held"] <= gates["holding"]
    assert 0.0 < gates["null_written_and_held"] < gates["null_holding"]
    assert "reward_loss" in record["final_metrics"]


def record_on_disk(out):
    return json.loads(recall_probe.record_path(out, LENGTH, GATED, 0).read_text())


def test_same_seed_same_numbers(swept):
    _, (record,) = swept
    again = recall_probe.run_probe(LENGTH, GATED, 0, UPDATES, EPISODES, SIZE)
    assert {k: v for k, v in again.items() if k != "wall_s"} == \
        {k: v for k, v in record.items() if k != "wall_s"}


def test_a_second_sweep_keeps_the_records(swept, monkeypatch):
    out, (record,) = swept

    def refuse(*args, **kwargs):
        raise AssertionError("a kept record was measured again")

    monkeypatch.setattr(recall_probe, "run_probe", refuse)
    assert recall_probe.sweep([LENGTH], [GATED], [0], UPDATES, EPISODES, out, SIZE) == [record]
    with pytest.raises(ConfigError, match="updates"):  # other settings: refused, not mixed
        recall_probe.sweep([LENGTH], [GATED], [0], UPDATES + 1, EPISODES, out, SIZE)
    assert record_on_disk(out) == record
    table = recall_probe.table([record])
    assert "| 3 | vsg:rate | 1 |" in table


def test_the_report_holds_every_record_with_the_same_settings(swept, tmp_path):
    """Records of earlier sweeps with the same settings join the table, in the default
    variants' order; one measured with other settings stays out."""
    _, (record,) = swept
    others = [{**record, "variant": "vsg:release", "seed": 1},
              {**record, "variant": "dreamerv2", "seed": 0},
              {**record, "variant": "vsg:rate", "seed": 0, "updates": UPDATES + 1}]
    for i, other in enumerate([record, *others]):
        (tmp_path / f"L{LENGTH}-{i}-s0.json").write_text(json.dumps(other))
    settings = {"updates": UPDATES, "eval_episodes": EPISODES, "size": SIZE}
    kept = recall_probe.all_records(tmp_path, settings)
    assert [r["variant"] for r in kept] == ["dreamerv2", "vsg:release", "vsg:rate"]


@pytest.mark.parametrize("lengths, variant, message", [
    ([0], "vsg", "env.memory_length"),
    ([3], "vsgg", "did you mean 'vsg'"),
    ([3], "vsg:sparse", "release, rate, rate_kl, gatel0rd"),
    ([3], "dreamerv2:rate", "has none"),
    ([3], "dreamerpro", "valid: .*dreamerv2"),
    ([3], "vsg:", "'model', 'model:objective'"),
    ([3], "vsg:rate@wm.gate_lambda", "'@key=value' overrides"),
    ([3], "vsg:rate@wm.gate_lambda=-1", "wm.gate_lambda"),
    ([3], "vsg:rate@wm.gate_lamda=0.1", "did you mean 'wm.gate_lambda'"),
    ([3], "vsg@train.seed=3", "the seed --seeds"),
])
def test_bad_input_is_refused_before_anything_is_written(tmp_path, lengths, variant, message):
    out = tmp_path / "probe"
    with pytest.raises(ConfigError, match=message):
        variants = [Variant.parse(variant)]
        recall_probe.sweep(lengths, variants, [0], UPDATES, EPISODES, out, SIZE)
    assert not out.exists()


def test_a_variant_carries_its_overrides_into_the_config_and_the_record_name(tmp_path):
    variant = Variant.parse("vsg:rate@wm.gate_lambda=0.05@wm.gate_noise=0.2")
    assert variant == Variant("vsg", "rate", ("wm.gate_lambda=0.05", "wm.gate_noise=0.2"))
    assert Variant.parse(variant.name) == variant
    config = recall_probe.probe_config(LENGTH, variant, 0, SIZE)
    assert (config.wm.gate_objective, config.wm.gate_lambda, config.wm.gate_noise) == \
        ("rate", 0.05, 0.2)
    path = recall_probe.record_path(tmp_path, LENGTH, variant, 0)
    assert path.name == "L3-vsg-rate-wm.gate_lambda=0.05-wm.gate_noise=0.2-s0.json"
    assert path != recall_probe.record_path(tmp_path, LENGTH, GATED, 0)


def test_the_cli_writes_the_table_and_the_figure_of_every_kept_record(swept, tmp_path):
    out, (record,) = swept
    copy = tmp_path / "probe"
    copy.mkdir()
    for path in out.glob("*.json"):
        (copy / path.name).write_text(path.read_text())
    argv = ["--lengths", str(LENGTH), "--variants", GATED.name, "--updates", str(UPDATES),
            "--eval-episodes", str(EPISODES), "--size", SIZE, "--out", str(copy)]
    assert recall_probe.main(argv) == 0  # every record kept: nothing is trained
    report = (copy / "report.md").read_text()
    assert "| 3 | vsg:rate | 1 |" in report and "(accuracy.png)" in report
    assert (copy / "accuracy.png").stat().st_size > 0


def test_cli_names_the_bad_value(tmp_path, capsys):
    with pytest.raises(SystemExit):
        recall_probe.main(["--variants", "dreamerv2:gatel0rd", "--out", str(tmp_path / "p")])
    assert "dreamerv2" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()
