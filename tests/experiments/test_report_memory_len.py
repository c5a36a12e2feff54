"""The report's ``memory_len`` figure and tables from hand-written run files
(experiments/report/memory_len.py): bsuite's regret ratio and score computed by bsuite's own
analysis code from the training episodes, success from the last evaluation, the gates' table,
missing runs."""

from __future__ import annotations

import json

import pytest

from experiments import report
from experiments.report import Context
from experiments.report.memory_len import memory_len_data, verdicts
from experiments.report.runs import ReportWarning
from experiments.spec import load_experiment
from vsgjax.agents.dreamer.gate_statistics import null_holding, null_holding_in, window_segments


def runs_by(experiment, method, seed):
    return next(r for r in experiment.runs if r.method == method and r.seed == seed)


def write_run(run, root, returns, last_eval, gates=None):
    logdir = run.logdir(root)
    logdir.mkdir(parents=True, exist_ok=True)
    lines = [{"step": 10 * i, "episode/return": r, "episode/length": 11}
             for i, r in enumerate(returns)]
    if gates:
        lines.append({"step": 10 * len(returns), **{f"gates/{k}": v for k, v in gates.items()}})
    (logdir / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    score = {"task": run.task, "method": run.method, "seed": str(run.seed),
             "xs": [100.0, 200.0], "ys": [0.0, last_eval], "wall_s": [30.0, 120.0]}
    (logdir / "scores.jsonl").write_text(json.dumps(score) + "\n")


def test_bsuite_scores_success_gates_and_missing_runs(tmp_path):
    experiment = load_experiment("memory_len", seeds=2)
    ep = lambda perfect, total=100: [1.0] * perfect + [-1.0] * (total - perfect)
    write_run(runs_by(experiment, "DreamerV2-L10", 0), tmp_path, ep(80), 0.9)  # ratio 0.4
    write_run(runs_by(experiment, "DreamerV2-L20", 0), tmp_path, ep(50), 0.0)  # ratio 1.0
    write_run(runs_by(experiment, "DreamerV2-L30", 0), tmp_path, ep(0), -1.0)  # ratio 2.0
    write_run(runs_by(experiment, "DreamerV2-L10", 1), tmp_path, ep(100), 1.0)
    # the logged nulls are replaced by those of MemoryChain's episodes in the training windows
    gates = {"open": 0.4, "closed_run_p90": 3.0, "null_run_p90": 99.0, "closed_run_max": 9.0,
             "null_run_max": 99.0, "holding_10": 0.25, "null_holding_10": 0.9,
             "prob_step1": 0.9, "prob_other_steps": 0.1, "written_and_held_10": 0.02}
    write_run(runs_by(experiment, "VSG-gatel0rd-L10", 0), tmp_path, ep(60), 0.5, gates)
    live = {**gates, "open": 0.1, "live_units": 0.1, "open_live": 0.2, "live_holding_20": 0.5,
            "live_null_holding_20": 0.9, "live_prob_step1": 0.7, "live_prob_other_steps": 0.1}
    write_run(runs_by(experiment, "VSG-gatel0rd-lambda0.1-L20", 0), tmp_path, ep(50), 0.0, live)

    data = memory_len_data(Context.create(experiment, tmp_path),
                           "bsuite_memory_len_published.json")
    assert data.series == ["DreamerV2", "VSG", "VSG-gatel0rd", "VSG-gatel0rd-lambda0.1"]
    assert data.lengths == [10, 20, 30]
    first = data.of("DreamerV2", 10)
    assert [r.regret_ratio for r in first] == pytest.approx([0.4, 0.0])
    assert [r.success for r in first] == pytest.approx([0.95, 1.0])
    assert [r.learned for r in first] == [True, True]
    assert not data.of("DreamerV2", 20)[0].learned
    assert data.scores == {"DreamerV2": [pytest.approx(1 / 3)]}  # seed 1 lacks L20, L30
    assert len(data.missing) == 2 * 10 - 6
    assert set(data.published) == {"DreamerV3", "R2I"}

    built = report.build_report(experiment, tmp_path, tmp_path / "out")
    section = next(s for s in built.sections if s.kind == "memory_len")
    assert [p.name for p in section.files] == ["memory_len.png", "memory_len.pdf",
                                               "memory_len.md"]
    assert "| 10 | 0.97 ± 0.03 (2); learned 2/2 |" in section.markdown
    assert "| DreamerV2 | 0.33 | 0.33 |" in section.markdown
    # open 0.4 in 12-step episodes: p90 5 (1 - 0.6^5 >= 0.9), the longest of the runs capped
    # at an episode; 10 closed steps in one 12-step episode are rare (null_holding_in), and
    # written at step 1 or 2, closed 9 steps: (1 - 0.6²) 0.6⁹
    gated = data.of("VSG-gatel0rd", 10)[0].gates
    assert gated["null_run_p90"] == 5.0 and gated["null_run_max"] == 12.0
    rows = window_segments(12, 64)
    assert gated["null_holding_10"] == pytest.approx(null_holding_in(0.4, 10, rows))
    assert 0.02 < gated["null_holding_10"] < null_holding(0.4, 10, 64) / 2
    assert gated["null_written_and_held_10"] == pytest.approx((1 - 0.6 ** 2) * 0.6 ** 9)
    assert "| VSG-gatel0rd | 10 | 0.40 | 3.0 (5.0) | 9 (12) | 0.250 " \
        f"({gated['null_holding_10']:.3f}) | 0.020 (0.006) | 0.90 / 0.10 |" in section.markdown
    # the live units' table: the L = 10 run predates the live statistics
    assert "| VSG-gatel0rd | 10 | — | — | — (—) | — / — |" in section.markdown
    live_null = null_holding_in(0.2, 20, window_segments(22, 64))
    assert f"| VSG-gatel0rd-lambda0.1 | 20 | 0.10 | 0.20 | 0.500 ({live_null:.3f}) | " \
        "0.70 / 0.10 |" in section.markdown
    assert "a reduced budget" in section.markdown


def test_each_length_is_compared_with_the_baseline_by_its_std(tmp_path):
    experiment = load_experiment("memory_len", seeds=2)
    ep = [1.0] * 10
    for seed, last in ((0, 1.0), (1, 0.0)):  # DreamerV2 at L = 20: success 1.0 and 0.5
        write_run(runs_by(experiment, "DreamerV2-L20", seed), tmp_path, ep, last)
        write_run(runs_by(experiment, "VSG-gatel0rd-lambda0.1-L20", seed), tmp_path, ep, 1.0)
        write_run(runs_by(experiment, "VSG-L20", seed), tmp_path, ep, -0.9)
    write_run(runs_by(experiment, "VSG-L10", 0), tmp_path, ep, 1.0)  # one seed: no verdict
    data = memory_len_data(Context.create(experiment, tmp_path), baseline="DreamerV2")
    lines = verdicts(data)
    assert lines == [
        "- L = 20: VSG − DreamerV2 = -0.70 (DreamerV2's std 0.25): below the baseline by more "
        "than one std.",
        "- L = 20: VSG-gatel0rd-lambda0.1 − DreamerV2 = +0.25 (DreamerV2's std 0.25): within "
        "one std of the baseline.", ""]
    with pytest.warns(ReportWarning, match="baseline 'Dreamer' is not a series .*DreamerV2"):
        assert memory_len_data(Context.create(experiment, tmp_path),
                               baseline="Dreamer").baseline is None


def test_cue_unit_records_sit_beside_the_success_of_their_checkpoint(tmp_path):
    experiment = load_experiment("memory_len", seeds=2)
    cue_dir = tmp_path / "memory_len" / "cue_units"
    cue_dir.mkdir(parents=True)
    record = {"step": 200, "cue_units": 6, "cue_units_held": 3, "cue_gated_units": 12,
              "readout_all": 1.0, "readout_held": 0.98, "actor_accuracy": 0.97}
    for seed, step in ((0, 200), (1, 100)):  # seed 1's record is of an earlier checkpoint
        run = runs_by(experiment, "VSG-gatel0rd-lambda0.1-L20", seed)
        write_run(run, tmp_path, [1.0] * 20, 1.0)
        (cue_dir / f"{run.method_dir}-s{seed}.json").write_text(
            json.dumps({**record, "step": step}))
    plain = runs_by(experiment, "DreamerV2-L20", 0)
    write_run(plain, tmp_path, [1.0] * 20, 0.0)
    (cue_dir / f"{plain.method_dir}-s0.json").write_text(json.dumps(
        {"step": 200, "cue_units": 90, "readout_all": 0.99, "actor_accuracy": 0.51}))
    with pytest.warns(ReportWarning, match="env step 100, the run ends at 200: left out"):
        data = memory_len_data(Context.create(experiment, tmp_path))
    assert data.of("VSG-gatel0rd-lambda0.1", 20)[1].cue == {}
    built = report.build_report(experiment, tmp_path, tmp_path / "out")
    section = next(s for s in built.sections if s.kind == "memory_len")
    table = section.markdown
    assert "| VSG-gatel0rd-lambda0.1 | 20 | 1.00 | 6 | 3 | 12 | 1.00 | 0.98 | 0.97 |" in table
    assert "| DreamerV2 | 20 | 0.50 | 90 | — | — | 0.99 | — | 0.51 |" in table
