"""Run directories written by an earlier version (tests/fixtures/rundir_v1) still load with
``vsgjax.load``, evaluate and resume.

The fixtures are two tiny debug runs written before the package was split into model/, envs/,
data/ and loop/: a host-loop run of ``bbs_basic`` and a device-loop run of
``mjx_cartpole_swingup`` (videos and TensorBoard files left out).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import vsgjax
from vsgjax import train
from vsgjax.analysis.evaluation import evaluate_logdir

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "rundir_v1"
RUNS = {
    "bbs_basic-vsg-debug": ["--task", "bbs_basic", "--model", "vsg", "--size", "debug",
                            "env.time_limit=200", "train.eval_every=200", "train.ckpt_every=100"],
    "mjx_cartpole_swingup-vsg-debug": [
        "--task", "mjx_cartpole_swingup", "--model", "vsg", "--size", "debug",
        "env.time_limit=40", "env.num_envs=2", "train.length=8", "train.batch=3",
        "train.train_every=5", "train.prefill=80", "train.pretrain=2", "train.ckpt_every=4",
        "train.eval_every=160"],
}


@pytest.fixture
def copied(tmp_path, request) -> Path:
    logdir = tmp_path / request.param
    shutil.copytree(FIXTURES / request.param, logdir)
    return logdir


@pytest.mark.parametrize("copied", list(RUNS), indirect=True)
def test_an_old_run_directory_loads_and_evaluates(copied):
    run = vsgjax.load(copied)
    step = json.loads((copied / "scores.jsonl").read_text())["xs"][-1]
    assert run.step == step
    posts = run.observe(run.episode(-1))
    assert np.all(np.isfinite(np.asarray(run.reward(posts))))
    infos, at = evaluate_logdir(copied, episodes=1)
    assert at == step and len(infos) == 1 and np.isfinite(infos[0]["return"])


@pytest.mark.parametrize("copied", list(RUNS), indirect=True)
def test_an_old_run_directory_resumes(copied, capsys):
    before = json.loads((copied / "scores.jsonl").read_text())["xs"][-1]
    steps = int(before) + 80
    flags = [a for a in RUNS[copied.name] if "=" not in a]
    overrides = [a for a in RUNS[copied.name] if "=" in a]
    code = train.main([*flags, "--seed", "0", "--logdir", str(copied), "--no-progress",
                       *overrides, f"train.steps={steps}"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert f"resuming from ckpt-{int(before):012d}.ckpt" in out
    assert f"done: {steps} env steps" in out
    scores = json.loads((copied / "scores.jsonl").read_text())
    assert scores["xs"][-1] == steps and len(scores["xs"]) == len(scores["ys"])
