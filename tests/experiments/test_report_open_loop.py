"""The report's ``open_loop`` figure and table from hand-written ``open_loop.jsonl`` files
(experiments/report/open_loop.py): per imagined step, mean +- std over seeds of each seed's last
evaluation (or the one nearest ``at``), the table at imagined steps 5, 15, 35, missing runs."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from experiments import report
from experiments.report import Context, ReportWarning
from experiments.spec import load_experiment

TASK = "mjx_cartpole_swingup"


def experiment_with_open_loop(**figure):
    experiment = load_experiment("cpu_proprio", seeds=2)
    return dataclasses.replace(experiment, figures=({"kind": "open_loop", **figure},))


def write_open_loop(run, root, lines: list[tuple[int, list, list]]):
    logdir = run.logdir(root)
    logdir.mkdir(parents=True, exist_ok=True)
    path = logdir / "open_loop.jsonl"
    path.write_text("".join(json.dumps({"step": step, "obs_mse": list(obs),
                                        "reward_mse": list(reward)}) + "\n"
                            for step, obs, reward in lines))
    return path


def errors(scale: float, length: int = 35) -> list[float]:
    """Errors growing with the imagined step: scale * k at step k."""
    return [scale * k for k in range(1, length + 1)]


def runs_of(experiment, method):
    return sorted((r for r in experiment.runs if r.task == TASK and r.method == method),
                  key=lambda r: r.seed)


def test_open_loop_lines_table_and_missing_runs(tmp_path):
    experiment = experiment_with_open_loop()
    vsg, dreamer = runs_of(experiment, "VSG"), runs_of(experiment, "DreamerV2")
    for run, scale in zip(vsg, (1.0, 3.0), strict=True):  # the last line counts
        write_open_loop(run, tmp_path, [(4_000, errors(100.0), errors(100.0)),
                                        (8_000, errors(scale), errors(scale / 10))])
    write_open_loop(dreamer[0], tmp_path, [(8_000, errors(5.0, 14), errors(0.5, 14))])
    write_open_loop(dreamer[1], tmp_path, [])  # a file without an evaluation yet
    context = Context.create(experiment, tmp_path)
    data = report.open_loop_data(context)
    line = data.lines[TASK]["obs_mse"]["VSG"]
    assert list(line.x) == list(range(1, 36)) and line.steps == [8_000, 8_000]
    np.testing.assert_allclose(line.mean, 2.0 * line.x)  # seeds 1k and 3k: mean 2k, std k
    np.testing.assert_allclose(line.std, 1.0 * line.x)
    assert list(line.n) == [2] * 35
    np.testing.assert_allclose(data.lines[TASK]["reward_mse"]["VSG"].mean, 0.2 * line.x)
    short = data.lines[TASK]["obs_mse"]["DreamerV2"]  # one seed, a 14-step test
    assert list(short.x) == list(range(1, 15)) and short.at(5) == (25.0, 0.0, 1)
    mean, _, n = short.at(15)
    assert n == 0 and math.isnan(mean)
    assert dreamer[1] in data.missing and "DrQ-v2" not in data.lines[TASK]["obs_mse"]
    assert not any(run in data.missing for run in runs_of(experiment, "DrQ-v2"))  # no world model

    built = report.build_report(experiment, tmp_path, tmp_path / "out")
    section = built.sections[0]
    assert section.kind == "open_loop"
    assert [p.name for p in section.files] == ["open_loop.png", "open_loop.pdf"]
    assert section.files[0].read_bytes().startswith(b"\x89PNG")
    rows = {tuple(cell.strip() for cell in line.split("|")[1:3]): line
            for line in section.markdown.splitlines() if line.startswith(f"| {TASK}")}
    assert rows[(TASK, "VSG")].split(" | ")[2:6] == [
        "8k", "10 ± 5 (n=2)", "30 ± 15 (n=2)", "70 ± 35 (n=2)"]  # obs MSE at steps 5, 15, 35
    assert "1 ± 0.5 (n=2)" in rows[(TASK, "VSG")]  # reward MSE at step 5
    assert rows[(TASK, "DreamerV2")].split(" | ")[3:6] == ["25 ± 0 (n=1)", "—", "—"]
    assert (TASK, "DrQ-v2") not in rows
    assert f"{dreamer[1].logdir(tmp_path) / 'open_loop.jsonl'}" in section.markdown
    assert "![open_loop](open_loop.png)" in built.markdown.read_text()


def test_at_picks_the_evaluation_nearest_to_a_step_within_a_bin(tmp_path):
    experiment = experiment_with_open_loop(at=4_500)
    vsg = runs_of(experiment, "VSG")
    write_open_loop(vsg[0], tmp_path, [(4_000, errors(1.0), errors(1.0)),
                                       (8_000, errors(9.0), errors(9.0))])
    write_open_loop(vsg[1], tmp_path, [(40_000, errors(1.0), errors(1.0))])  # too far
    context = Context.create(experiment, tmp_path)
    data = report.open_loop_data(context, 4_500)
    line = data.lines[TASK]["obs_mse"]["VSG"]
    assert line.steps == [4_000] and line.at(35) == (35.0, 0.0, 1)
    assert vsg[1] in data.missing and "no evaluation within" in data.why[vsg[1]]
    assert "nearest to env step 4.5k" in report.build_report(
        experiment, tmp_path, tmp_path / "out").sections[0].markdown


def test_a_corrupt_line_is_skipped_with_a_warning(tmp_path):
    experiment = experiment_with_open_loop()
    run = runs_of(experiment, "VSG")[0]
    path = write_open_loop(run, tmp_path, [(4_000, errors(1.0), errors(1.0))])
    path.write_text(path.read_text() + '{"step": 8000, "obs_mse": [1, 2\n'
                    + json.dumps({"step": 9000, "obs_mse": [1.0]}) + "\n")
    with pytest.warns(ReportWarning) as caught:
        records = report.read_open_loop(path)
    assert [r["step"] for r in records] == [4_000]
    assert len(caught) == 2
