"""The fault battery's rows for bad inputs and damaged run directories seen from outside
training: each is a case a new user can hit, and each must end in a clear message (or a
state that says what is wrong) with nothing written, never in a traceback, a mixed report or
a ``done`` that is not.

- a log directory holding another model's run in a slot: ``launch --status`` and ``report``
  both leave it out (one function decides for both), and the report names it;
- ``launch --status`` on a run whose ``scores.jsonl`` is corrupt, or whose checkpoints are all
  corrupt: ``damaged``, not ``done``;
- background videos that do not decode (a text file named ``.mp4``, a truncated video, an
  empty file, an unreadable one): ``vsgjax.train`` refuses, naming the file and why, before it
  creates the log directory;
- a replay (and agent) that cannot fit in memory, device and host loop: refused before the log
  directory exists, naming the estimate and what is available;
- ``env.hide`` with an empty key (a trailing comma): refused, naming the value and the keys;
- reading a background video in a process running JAX forks nothing (no ``os.fork()``
  warning).
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import cv2
import imageio.v3 as iio
import jax.numpy as jnp
import numpy as np
import pytest

from experiments import launch, report
from experiments.spec import load_experiment
from vsgjax import train
from vsgjax.config import make_config, to_dict
from vsgjax.data import checkpoint
from vsgjax.envs.backgrounds import read_video

STEPS = 400
DEFINITION = f"""
description = "fault battery: two models of one task"
steps = {STEPS}
seeds = 1

[[groups]]
tasks = ["bbs_basic"]
models = ["vsg", "dreamerv2"]
overrides = ["env.time_limit=200"]
"""
VIDEO_TASK = "dmc_cartpole_balance"


@pytest.fixture
def slots(tmp_path) -> dict:
    """The two runs of the ``pair`` experiment (debug size) under ``tmp_path/root``, each with
    its own config.json and scores, and a checkpoint at its last step."""
    definitions = tmp_path / "definitions"
    definitions.mkdir()
    (definitions / "pair.toml").write_text(DEFINITION)
    experiment = load_experiment("pair", "debug", paper_dir=definitions)
    root = tmp_path / "root"
    jobs = launch.make_jobs(experiment, root)
    for job in jobs:
        write_run(job.job_dir, job.run.config(), job.run.method)
    return {"experiment": experiment, "root": root, "jobs": {j.run.model: j for j in jobs}}


def write_run(logdir: Path, config, method: str) -> None:
    logdir.mkdir(parents=True, exist_ok=True)
    (logdir / "config.json").write_text(json.dumps(to_dict(config), indent=2))
    record = {"task": config.env.task, "method": method, "seed": str(config.train.seed),
              "xs": [200.0, float(STEPS)], "ys": [1.0, 2.0]}
    (logdir / "scores.jsonl").write_text(json.dumps(record) + "\n")
    checkpoint.save(logdir / "checkpoints", STEPS, {"w": np.zeros(3, np.float32)},
                    {"counters": {}})


def test_a_run_of_another_model_in_a_slot_is_left_out_by_status_and_report(slots):
    vsg, dreamerv2 = slots["jobs"]["vsg"], slots["jobs"]["dreamerv2"]
    write_run(dreamerv2.job_dir, vsg.run.config(), vsg.run.method)  # a VSG run in the slot
    status = launch.job_status(dreamerv2)
    assert status.state == "config differs" and "agent: 'vsg' -> 'dreamerv2'" in status.note
    assert launch.job_status(vsg).state == "done"
    built = report.build_report(slots["experiment"], slots["root"], slots["root"] / "out")
    assert built.missing == [dreamerv2.run]
    text = built.markdown.read_text()
    assert "1 of 2 runs have no results" in text
    line = next(line for line in text.splitlines() if line.startswith("- bbs_basic/DreamerV2"))
    assert str(dreamerv2.job_dir / "config.json") in line
    assert "config differs: " + status.note in line


def test_a_run_of_another_seed_in_a_slot_is_left_out(slots):
    vsg = slots["jobs"]["vsg"]
    other = make_config("bbs_basic", "vsg", "debug",
                        ["train.seed=1", *vsg.run.config_overrides])
    write_run(vsg.job_dir, other, vsg.run.method)
    assert launch.job_status(vsg).note == "train.seed: 1 -> 0"
    assert report.build_report(slots["experiment"], slots["root"],
                               slots["root"] / "out").missing == [vsg.run]


def test_status_shows_a_corrupt_scores_file_as_damaged(slots):
    job = slots["jobs"]["vsg"]
    (job.job_dir / "scores.jsonl").write_text('{"task": "bbs_basic", "xs": [200.0, 4')
    status = launch.job_status(job)
    assert status.state == "damaged" and not status.launchable
    assert "scores.jsonl line 1 is not JSON" in status.note and "--restart" in status.note


def test_status_shows_a_run_whose_checkpoints_are_all_corrupt_as_damaged(slots):
    job = slots["jobs"]["vsg"]
    newest = checkpoint.checkpoint_path(job.job_dir / "checkpoints", STEPS)
    older = checkpoint.checkpoint_path(job.job_dir / "checkpoints", STEPS // 2)
    older.write_bytes(newest.read_bytes())  # an intact one before it
    newest.write_bytes(newest.read_bytes()[:-5])  # cut short
    status = launch.job_status(job)
    assert (status.state, status.step) == ("partial", STEPS)
    assert status.note.startswith(f"resumes from env step {STEPS // 2} (corrupt: {newest.name}")
    older.write_bytes(b"not a checkpoint")
    status = launch.job_status(job)
    assert status.state == "damaged" and not status.launchable
    assert f"no intact checkpoint ({newest.name}: payload has" in status.note
    assert f"{older.name}: " in status.note


# --- background videos -------------------------------------------------------------------------


def write_mp4(path: Path, frames: int = 6) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10, (16, 16))
    for t in range(frames):
        writer.write(np.full((16, 16, 3), 40 * t, np.uint8))
    writer.release()


def make_bad(kind: str, path: Path) -> None:
    if kind == "text":
        path.write_text("not a video")
    elif kind == "truncated":
        write_mp4(path)
        path.write_bytes(path.read_bytes()[:400])
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "a folder":
        path.mkdir()
    elif kind == "no permission":
        write_mp4(path)
        path.chmod(0)


BAD_VIDEOS = {"text": "FFmpeg cannot open it", "truncated": "FFmpeg cannot open it",
              "empty": "it is empty", "a folder": "it cannot be read (Is a directory)",
              "no permission": "it cannot be read (Permission denied)"}


@pytest.mark.parametrize("kind", BAD_VIDEOS)
def test_a_video_that_does_not_decode_is_refused_before_anything_is_written(kind, tmp_path,
                                                                            capsys):
    if kind == "no permission" and os.geteuid() == 0:
        pytest.skip("root reads a file without read permission")
    folder = tmp_path / "videos"
    folder.mkdir()
    write_mp4(folder / "a_good.mp4")
    make_bad(kind, folder / "b_bad.mp4")
    logdir = tmp_path / "run"
    assert train.main(["--task", VIDEO_TASK, "--size", "debug", "--logdir", str(logdir),
                       "env.background=video", f"env.background_dir={folder}"]) == 2
    err = capsys.readouterr().err
    assert f"video 'b_bad.mp4' does not decode: {BAD_VIDEOS[kind]}" in err
    assert "Traceback" not in err and not logdir.exists()


def test_reading_a_video_under_jax_forks_nothing(tmp_path):
    jnp.ones(3).block_until_ready()  # JAX's threads are running
    write_mp4(tmp_path / "clip.mp4")
    greys = np.arange(3, dtype=np.uint8)[:, None, None, None] * 100
    iio.imwrite(tmp_path / "clip.gif", np.broadcast_to(greys, (3, 16, 16, 3)), loop=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = [read_video(tmp_path / name, 8) for name in ("clip.mp4", "clip.gif")]
    assert [f.shape for f in frames] == [(6, 8, 8, 3), (3, 8, 8, 3)]
    assert abs(int(frames[0][5, 0, 0, 0]) - 200) <= 3  # the 6th frame's grey (lossy)
    np.testing.assert_array_equal(frames[1][:, 0, 0, 0], [0, 100, 200])
    assert not [w for w in caught if "fork" in str(w.message)]


# --- memory and observation keys ---------------------------------------------------------------


def test_a_device_loop_replay_that_cannot_fit_is_refused_before_anything_is_written(tmp_path,
                                                                                   capsys):
    logdir = tmp_path / "run"
    assert train.main(["--task", "mjx_cartpole_swingup", "--size", "debug", "--logdir",
                       str(logdir), "--no-progress",
                       "train.replay_capacity=100000000000"]) == 2
    err = capsys.readouterr().err
    assert "this run needs at least " in err and "TiB of host memory" in err
    assert "replay " in err and "is available (train.replay_capacity=100000000000" in err
    assert not logdir.exists()


def test_a_host_loop_run_that_cannot_fit_is_refused_before_anything_is_written(
        tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("vsgjax.loop.memory_check.available_host_bytes", lambda: 2**20)
    logdir = tmp_path / "run"
    assert train.main(["--task", "bbs_basic", "--size", "debug", "--logdir", str(logdir),
                       "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "MiB of host memory (agent state " in err and "1 MiB is available" in err
    assert not logdir.exists()


@pytest.mark.parametrize("value", ["velocity,", ",velocity", "position,,velocity"])
def test_an_empty_observation_key_is_refused_naming_the_value_and_the_keys(value, tmp_path,
                                                                           capsys):
    logdir = tmp_path / "run"
    assert train.main(["--task", "mjx_cartpole_swingup", "--size", "debug", "--logdir",
                       str(logdir), f"env.hide={value}"]) == 2
    err = capsys.readouterr().err
    assert f"env.hide={value!r} has an empty key; valid: comma-separated keys of position, " \
           "velocity" in err
    assert not logdir.exists()
