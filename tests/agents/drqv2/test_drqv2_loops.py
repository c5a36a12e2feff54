"""DrQ-v2 through the agent interface in both loops: the host loop on pixels (a fake image
env), the device loop on an MJX task, resuming, ``vsgjax.load``, and its bad inputs."""

from __future__ import annotations

import functools
import json
import re

import numpy as np
import pytest

import vsgjax
from tests.support.fake_envs import FakeImageEnv
from vsgjax import train
from vsgjax.config import make_config
from vsgjax.data.collect import EnvBatch
from vsgjax.envs.wrappers import DefaultSeed
from vsgjax.loop.host_trainer import HostTrainer
from vsgjax.registry.agents import gated_models


def fake_pixel_env(seed: int) -> DefaultSeed:
    return DefaultSeed(FakeImageEnv(length=6, size=16), seed)


def fake_envs(env_cfg, seed: int, num_envs: int, *, eval: bool = False) -> EnvBatch:
    base = seed + 1000 if eval else seed
    return EnvBatch([functools.partial(fake_pixel_env, base + i) for i in range(num_envs)],
                    workers=False)


def host_config(steps: int):
    return make_config("dmc_walker_walk", "drqv2", "debug",
                       [f"train.steps={steps}", "train.prefill=40", "train.eval_every=60",
                        "env.time_limit=40",  # the fake env's episodes are shorter still
                        "train.log_every=20", "train.ckpt_every=10"])


def test_the_host_loop_trains_drqv2_on_pixels_and_resumes(tmp_path):
    trainer = HostTrainer(host_config(120), tmp_path, make_envs=fake_envs, progress=False)
    try:
        assert trainer.agent.replay == (2, 2)  # walker's n = 1: obs and next obs, 2 before
        assert trainer.runs[0].replay.history == 2
        assert trainer.run() == 0
        first_updates = trainer.counters.updates
    finally:
        trainer.close()
    assert first_updates > 0
    metrics = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert any("train/critic/loss" in m for m in metrics)
    trainer = HostTrainer(host_config(160), tmp_path, make_envs=fake_envs, progress=False)
    try:
        assert trainer.resumed and trainer.counters.updates == first_updates
        assert trainer.run() == 0 and trainer.counters.updates > first_updates
    finally:
        trainer.close()
    run = vsgjax.load(tmp_path)
    obs = {"image": np.zeros((3, 16, 16, 3), np.uint8), "is_first": np.ones(3, bool)}
    _, action = run.act(obs)
    assert action.shape == (3, 2) and np.all(np.abs(np.asarray(action)) <= 1)


def test_the_device_loop_trains_drqv2_on_an_mjx_task(tmp_path):
    logdir = tmp_path / "run"
    assert train.main(["--task", "mjx_cartpole_swingup", "--model", "drqv2", "--size", "debug",
                       "--logdir", str(logdir), "--no-progress", "train.steps=2000"]) == 0
    scores = json.loads((logdir / "scores.jsonl").read_text())
    assert scores["method"] == "DrQ-v2" and scores["xs"][-1] == 2000
    run = vsgjax.load(logdir)
    assert run.step == 2000
    gated = re.escape(f"({', '.join(gated_models())})")
    with pytest.raises(ValueError, match=rf"'drqv2' has no gates.*{gated}"):
        vsgjax.gate_statistics(run.params, {})
    with pytest.raises(ValueError, match="no world model"):
        _ = run.world_model


@pytest.mark.parametrize("argv, named", [
    (["--task", "atari_pong", "--model", "drqv2"], ("'drqv2'", "'atari_pong'", "discrete")),
    (["--task", "mjx_cartpole_swingup", "--model", "drqv2", "wm.lr=0.1"],
     ("'wm.lr'", "'drqv2'", "drq.*")),
    (["--task", "mjx_cartpole_swingup", "--model", "vsg", "drq.nstep=1"],
     ("'drq.nstep'", "'vsg'")),
])
def test_bad_input_fails_at_startup_naming_what_is_wrong(tmp_path, capsys, argv, named):
    assert train.main([*argv, "--size", "debug", "--logdir", str(tmp_path / "x")]) == 2
    error = capsys.readouterr().err
    assert all(part in error for part in named), error
    assert not (tmp_path / "x").exists()
