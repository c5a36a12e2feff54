"""End-to-end tests of ``python -m vsgjax.train`` / ``python -m vsgjax.evaluate`` on the CPU.

Training runs are subprocesses at the ``debug`` size with short episodes; they share one
persistent XLA compilation cache so that only the first run of each task compiles the update.
"""

from __future__ import annotations

import itertools
import json
import math
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.support.subprocess_env import subprocess_env
from vsgjax import train
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.analysis.evaluation import format_table
from vsgjax.config import make_config
from vsgjax.data import checkpoint
from vsgjax.loop import driver, schedule
from vsgjax.loop.evaluator import summarize
from vsgjax.loop.logger import Logger, truncate_metrics
from vsgjax.loop.run_state import restore_latest

ROOT = Path(__file__).resolve().parents[2]
# Short episodes so that a few hundred env steps hold several of them.
TASKS = {
    "bbs_basic": ["env.time_limit=200"],  # 51 agent steps per episode, action repeat 4
    "dmc_walker_walk": ["env.time_limit=100"],  # 50 agent steps, action repeat 2
    "atari_pong": ["env.time_limit=400", "train.steps=800"],  # 100 agent steps, repeat 4
}
RUN_TIMEOUT = 900


@pytest.fixture(scope="module")
def child_env() -> dict:
    return subprocess_env(PYTHONWARNINGS="default")


def train_command(logdir: Path, task: str, *overrides: str) -> list[str]:
    return [sys.executable, "-m", "vsgjax.train", "--task", task, "--model", "vsg",
            "--size", "debug", "--seed", "0", "--logdir", str(logdir), "--no-progress",
            *TASKS[task], *overrides]


def start(command: list[str], env: dict) -> subprocess.Popen:
    return subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def finish(process: subprocess.Popen) -> tuple[int, str, str]:
    out, err = process.communicate(timeout=RUN_TIMEOUT)
    return process.returncode, out, err


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture(scope="module")
def runs(tmp_path_factory, child_env) -> dict:
    """One finished debug run per task (run in parallel), plus a second bbs run, same seed."""
    root = tmp_path_factory.mktemp("runs")
    commands = {task: train_command(root / task, task) for task in TASKS}
    processes = {task: start(command, child_env) for task, command in commands.items()}
    results = {task: (root / task, *finish(p)) for task, p in processes.items()}
    again = root / "bbs_basic_again"
    results["bbs_basic_again"] = (again, *finish(start(train_command(again, "bbs_basic"),
                                                       child_env)))
    return results


# --- fast tests --------------------------------------------------------------------------------


def test_unknown_task_model_and_key_are_errors_listing_valid_values(capsys):
    assert train.main(["--task", "dmc_walker_fly", "--size", "debug"]) == 2
    assert "dmc_walker_walk" in capsys.readouterr().err
    assert train.main(["--task", "mujoco_ant"]) == 2
    assert "bbs_<variant>" in capsys.readouterr().err
    assert train.main(["--model", "dreamerv3"]) == 2
    assert "dreamerv1, dreamerv2, vsg, svsg, ssm" in capsys.readouterr().err
    assert train.main(["train.stepz=3"]) == 2
    assert "train.stepz" in capsys.readouterr().err


def test_size_auto_is_small_or_cpu_on_cpu_and_explicit_sizes_pass_through():
    gpu = train.has_gpu()
    assert train.resolve_size("auto", "bbs_basic")[0] == ("paper" if gpu else "small")
    assert train.resolve_size("auto", "mjx_walker_walk")[0] == ("paper" if gpu else "cpu")
    assert train.resolve_size("debug", "mjx_walker_walk") == ("debug", "as requested")


def test_next_multiple_and_env_seeds():
    assert [schedule.next_multiple(v, 100) for v in (0, 99, 100, 250)] == [100, 100, 200, 300]
    # evaluations on the grid prefill end + k·eval_every (1030, 1130, ...), never twice at once
    assert [schedule.next_on_grid(1030, v, 100) for v in (1030, 1129, 1130, 1390)] == [
        1130, 1130, 1230, 1430]
    assert schedule.env_seed(7, 0) == 7
    assert schedule.env_seed(7, 500) != schedule.env_seed(7, 600)


def test_the_first_evaluation_is_checkpointed_at_once_then_every_ckpt_every_updates():
    """A run killed after its first evaluation resumes from the checkpoint saved right after
    it (training refuses evaluations that no checkpoint resumes)."""
    config = make_config("mjx_cartpole_balance", "vsg", "debug", ["train.ckpt_every=10"])
    plan = schedule.Schedule(config)
    plan.counters.agent_steps = 40
    plan.start_training()
    plan.counters.updates = 3
    assert not plan.ckpt_due()  # no evaluation yet
    plan.eval_done()
    assert plan.ckpt_due()
    plan.ckpt_done()
    assert plan.counters.last_ckpt_step == plan.env_steps
    plan.counters.agent_steps, plan.counters.updates = 400, 12
    plan.eval_done()
    assert not plan.ckpt_due()  # later evaluations wait for ckpt_every
    plan.counters.updates = 13
    assert plan.ckpt_due()


def test_non_finite_names_update_and_bad_metrics():
    assert driver.non_finite({"wm/loss": 1.0}, 3, 120) is None
    problem = driver.non_finite({"wm/loss": math.nan, "actor/loss": 0.5}, 3, 120)
    assert re.search(r"update 3 \(env step 120\).*wm/loss=nan", problem)
    assert "actor/loss" not in problem


def test_logger_writes_null_for_nan_and_truncates_on_resume(tmp_path):
    logger = Logger(tmp_path)
    logger.scalars(10, {"a": 1.0, "b": math.nan}, prefix="x")
    logger.scalars(20, {"a": 2.0})
    logger.close()
    records = read_jsonl(tmp_path / "metrics.jsonl")
    assert records == [{"step": 10, "x/a": 1.0, "x/b": None}, {"step": 20, "a": 2.0}]
    with open(tmp_path / "metrics.jsonl", "a") as file:
        file.write('{"step": 30, "a"')  # a line cut short by a killed run
    assert truncate_metrics(tmp_path / "metrics.jsonl", 10) == 1
    assert read_jsonl(tmp_path / "metrics.jsonl") == [records[0]]


def test_summary_and_table_skip_nan_discovery_metrics():
    infos = [{"return": 1.0, "length": 10, "discovery/mean_first_visit": math.nan},
             {"return": 3.0, "length": 12, "discovery/mean_first_visit": 4.0}]
    summary = summarize(infos)
    assert summary == {"return": 2.0, "length": 11.0, "discovery/mean_first_visit": 4.0,
                       "return_std": 1.0}
    table = format_table(infos).splitlines()
    assert table[0].split() == ["episode", "return", "length", "discovery/mean_first_visit"]
    assert table[-1].split() == ["mean", "2.000", "11.000", "4.000"]
    assert "nan" in table[2]


@pytest.mark.slow
def test_non_finite_loss_stops_with_message_and_keeps_last_good_checkpoint(
        tmp_path, monkeypatch, capsys):
    """An update returning NaN at update 3 stops the run; checkpoints hold only updates <= 2."""
    def fake_train_step(self, state, batch, key):
        loss = jnp.where(state.step == 2, jnp.nan, 1.0)
        return state._replace(step=state.step + 1), {"wm/loss": loss}

    monkeypatch.setattr(DreamerAgent, "train_step", fake_train_step)
    code = train.main(["--size", "debug", "--logdir", str(tmp_path), "--no-progress",
                       "env.time_limit=200", "train.ckpt_every=1", "train.eval_every=100000"])
    err = capsys.readouterr().err
    assert code == 1
    assert "non-finite metrics at update 3" in err and "wm/loss=nan" in err
    assert "ckpt-" in err
    config = make_config("bbs_basic", "vsg", "debug", ["env.time_limit=200"])
    agent = DreamerAgent(config, (64, 64, 3), 2, False)
    restored = restore_latest(tmp_path / "checkpoints", agent, jax.random.PRNGKey(0))
    assert restored.meta["counters"]["updates"] == 2
    assert int(restored.tree["agent"].step) == 2


# --- end to end (subprocesses) -----------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("task", list(TASKS))
def test_training_writes_every_artefact(runs, task):
    logdir, code, out, err = runs[task]
    assert code == 0, err[-3000:]
    lines = out.splitlines()
    assert lines[0].startswith(f"vsgjax train: task={task} model=vsg size=debug")
    assert lines[1].startswith("device: cpu") and lines[2].startswith("host allocator: ")
    assert lines[3] == f"logdir: {logdir}"
    assert lines[4] == "overrides: " + " ".join(TASKS[task])
    assert lines[5] == "starting a new run"
    config = json.loads((logdir / "config.json").read_text())
    assert config["env"]["task"] == task and config["size"] == "debug"
    records = read_jsonl(logdir / "metrics.jsonl")
    trained = [r for r in records if "train/wm/loss" in r]
    assert trained and all(math.isfinite(r["train/wm/loss"]) for r in trained)
    assert any("episode/return" in r for r in records)
    assert any("eval/return" in r for r in records)
    assert list(logdir.glob("events.out.tfevents.*"))
    assert list((logdir / "episodes").glob("*.mcap"))
    assert list((logdir / "checkpoints").glob("ckpt-*.ckpt"))
    for name in ("eval", "open_loop"):
        assert list((logdir / "videos").glob(f"{name}_*.mp4")), name
    scores = read_jsonl(logdir / "scores.jsonl")
    assert len(scores) == 1 and set(scores[0]) == {"task", "method", "seed", "xs", "ys",
                                                   "wall_s", "cpu_s"}
    for clock in ("wall_s", "cpu_s"):  # the run's seconds at each evaluation, growing
        assert len(scores[0][clock]) == len(scores[0]["xs"]), clock
        assert 0 < scores[0][clock][0] <= scores[0][clock][-1], clock
    assert scores[0]["method"] == "VSG" and scores[0]["task"] == task
    assert scores[0]["xs"][-1] == config["train"]["steps"]
    assert len(scores[0]["xs"]) == len(scores[0]["ys"]) >= 2
    episodes = read_jsonl(logdir / "eval_episodes.jsonl")
    assert len(episodes) == len(scores[0]["xs"]) * config["train"]["eval_episodes"]
    # the release's schedule: pretraining updates and a first evaluation when prefill ends, then
    # one update per train_every agent steps and an evaluation every eval_every env steps
    train_cfg, repeat = config["train"], config["env"]["action_repeat"]
    prefilled = int(re.search(r"prefill done at env step (\d+)", out).group(1))
    steps, updates = map(int, re.search(r"done: (\d+) env steps, (\d+) updates", out).groups())
    assert updates == (train_cfg["pretrain"] + 1
                       + (steps - prefilled) // repeat // train_cfg["train_every"])
    assert scores[0]["xs"][0] == prefilled
    evals = scores[0]["xs"][:-1]  # the last one is the final evaluation at train.steps
    assert all(b - a >= train_cfg["eval_every"] for a, b in itertools.pairwise(evals))
    if task.startswith("bbs"):
        assert {"discovery/mean_first_visit", "discovery/never_visited",
                "discovery/visited_not_scored", "discovery/episode_length"} <= set(episodes[0])


@pytest.mark.slow
def test_same_seed_gives_identical_metrics(runs):
    """Same seed, one env: the same updates on the same data, with the same losses.

    Counters must match exactly; losses to float32 rounding (two processes on a multi-threaded
    CPU backend were seen to differ in the last bit from the first update on).
    """
    first, second = ([r for r in read_jsonl(runs[name][0] / "metrics.jsonl")
                      if "train/wm/loss" in r] for name in ("bbs_basic", "bbs_basic_again"))
    assert first and len(first) == len(second)
    for a, b in zip(first, second, strict=True):
        assert a.keys() == b.keys()
        for key in ("step", "train/updates", "train/episodes", "train/replay_steps"):
            assert a[key] == b[key], key
        keys = sorted(k for k in a if k.startswith(("train/wm/", "train/actor/", "train/critic/",
                                                     "train/imag/")))
        np.testing.assert_allclose([a[k] for k in keys], [b[k] for k in keys], rtol=1e-5,
                                   atol=1e-6, err_msg=f"step {a['step']}")


@pytest.mark.slow
def test_evaluate_prints_a_table(runs, child_env):
    logdir = runs["bbs_basic"][0]
    result = subprocess.run([sys.executable, "-m", "vsgjax.evaluate", str(logdir),
                             "--episodes", "2"], cwd=ROOT, env=child_env, capture_output=True,
                            text=True, timeout=RUN_TIMEOUT)
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()
    assert "checkpoint at env step 400, 2 episodes" in lines[0]
    assert lines[1].split()[:3] == ["episode", "return", "length"]
    assert [line.split()[0] for line in lines[3:]] == ["0", "1", "-------", "mean"]


def wait_for(predicate, timeout: float, process: subprocess.Popen):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        if process.poll() is not None:
            raise AssertionError(f"run ended early: {process.communicate()}")
        time.sleep(0.2)
    process.kill()
    raise AssertionError("timed out")


def checkpoint_steps(logdir: Path) -> list[int]:
    return [step for step, _ in checkpoint.list_checkpoints(logdir / "checkpoints")]


@pytest.mark.slow
def test_sigkill_then_resume_continues_from_checkpoint_with_replay_and_sigterm_saves(
        tmp_path, child_env):
    command = train_command(tmp_path, "bbs_basic", "train.steps=100000", "train.eval_every=10000",
                            "train.ckpt_every=5")
    run = start(command, child_env)
    wait_for(lambda: checkpoint_steps(tmp_path), RUN_TIMEOUT, run)
    run.send_signal(signal.SIGKILL)
    run.communicate()
    killed_at = checkpoint_steps(tmp_path)[-1]
    episodes = sorted((tmp_path / "episodes").glob("*.mcap"))
    assert episodes
    # Corrupt files sorting last (newest): written after the checkpoint, like every episode
    # file the killed run wrote after it, they are moved aside, never read.
    (tmp_path / "episodes" / "zzzz-garbage.mcap").write_bytes(b"not an mcap file")
    data = episodes[0].read_bytes()
    (tmp_path / "episodes" / "zzzz-truncated.mcap").write_bytes(data[: len(data) // 2])

    run = start(command, child_env)  # the same command resumes
    wait_for(lambda: max(checkpoint_steps(tmp_path)) > killed_at, RUN_TIMEOUT, run)
    run.send_signal(signal.SIGTERM)
    code, out, err = finish(run)
    assert code == 128 + signal.SIGTERM, err[-3000:]
    match = re.search(r"^resuming from ckpt-\d+\.ckpt: env step (\d+), update (\d+), "
                      r"replay (\d+) steps in (\d+) episodes", out, flags=re.M)
    assert match, out[-3000:]
    assert int(match.group(1)) == killed_at
    moved = sorted(p.name for p in tmp_path.glob("previous/*/episodes/*.mcap"))
    assert {"zzzz-garbage.mcap", "zzzz-truncated.mcap"} <= set(moved)
    assert int(match.group(4)) + len(moved) - 2 == len(episodes)  # replay + moved: every one
    assert f"moved {len(moved)} episode file(s) written after" in out
    assert "skipping corrupt episode file" not in err
    stopped_at = int(re.search(r"SIGTERM: saved a checkpoint at env step (\d+)", out).group(1))
    assert checkpoint_steps(tmp_path)[-1] == stopped_at > killed_at
    steps = [r["step"] for r in read_jsonl(tmp_path / "metrics.jsonl") if "train/updates" in r]
    assert steps == sorted(steps) and len(steps) == len(set(steps))
