"""Run directories written by an earlier version (tests/fixtures/rundir_v1) still load with
``vsgjax.load``, evaluate and resume.

The fixtures are tiny debug runs (videos and TensorBoard files left out): two written before
the package was split into model/, envs/, data/ and loop/, a host-loop run of ``bbs_basic`` and
a device-loop run of ``mjx_cartpole_swingup``; and a device-loop DrQ-v2 run of
``mjx_cartpole_swingup`` written before configs were agent-owned. All three hold
``config.json`` format version 1 (every agent's sections, the model's name in ``model.name``;
vsgjax/config/saved.py), in the file and in their checkpoints.
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
DRQV2 = "mjx_cartpole_swingup-drqv2-debug"
DRQV2_ARGS = ["--task", "mjx_cartpole_swingup", "--model", "drqv2", "--size", "debug",
              "env.time_limit=40", "env.num_envs=2", "train.batch=3", "train.prefill=80",
              "train.ckpt_every=4", "train.eval_every=160"]


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


@pytest.mark.parametrize("copied", [DRQV2], indirect=True)
def test_an_old_drqv2_run_directory_loads_evaluates_and_resumes(copied, capsys):
    """Its version-1 config.json saved the Dreamer family's sections too; they are dropped, and
    the run resumes from its checkpoint (whose config is version 1 as well) with no difference
    found. ``train.steps`` at the saved step: the resume restores and stops, compiling no
    update; the resume rewrites config.json in the current format."""
    run = vsgjax.load(copied)
    step = json.loads((copied / "scores.jsonl").read_text())["xs"][-1]
    assert run.step == step and run.config.agent == "drqv2" and not hasattr(run.config, "wm")
    infos, at = evaluate_logdir(copied, episodes=1)
    assert at == step and len(infos) == 1 and np.isfinite(infos[0]["return"])
    flags = [a for a in DRQV2_ARGS if "=" not in a]
    overrides = [a for a in DRQV2_ARGS if "=" in a]
    code = train.main([*flags, "--seed", "0", "--logdir", str(copied), "--no-progress",
                       *overrides, f"train.steps={int(step)}"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert f"resuming from ckpt-{int(step):012d}.ckpt" in out
    assert "nothing to train" in out
    saved = json.loads((copied / "config.json").read_text())  # rewritten in the new format
    assert saved["version"] == 2 and saved["agent"] == "drqv2" and "wm" not in saved
