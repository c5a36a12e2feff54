"""Many seeds in one process (vsgjax.loop.parallel, the Trainer over S seeds) and sharded updates.

The in-process runs are BringBackShapes at the ``debug`` size with 50-step episodes; the
sharding test runs in a subprocess with two forced host devices (XLA reads the flag at start).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest

from tests.support.overrides import replaced
from vsgjax import train
from vsgjax.config import ConfigError, make_config
from vsgjax.data import checkpoint
from vsgjax.loop.host_trainer import HostTrainer
from vsgjax.loop.parallel import mesh_shape, stack, take
from vsgjax.loop.run_state import restore_latest

ROOT = Path(__file__).resolve().parents[2]
SHORT = ["env.time_limit=200", "train.eval_every=100000", "train.video_every=100000",
         "train.ckpt_every=3", "train.train_every=4"]
STEPS = 320  # prefill ends at 208 env steps (the first episodes end at 200, chunks of 16)


def configs(seeds, *overrides):
    return [make_config("bbs_basic", "vsg", "debug",
                        replaced([f"train.seed={s}", f"train.steps={STEPS}", *SHORT],
                                 *overrides))
            for s in seeds]


def run_trainer(configs, logdirs) -> tuple[int, HostTrainer]:
    trainer = HostTrainer(configs, logdirs, progress=False, out=lambda *_: None)
    try:
        return trainer.run(), trainer
    finally:
        trainer.close()


def train_records(logdir: Path) -> list[dict]:
    lines = (logdir / "metrics.jsonl").read_text().splitlines()
    return [r for r in map(json.loads, lines) if "train/updates" in r]


def scores(logdir: Path) -> dict:
    return json.loads((logdir / "scores.jsonl").read_text())


@pytest.fixture(scope="module")
def two_seeds(tmp_path_factory):
    """Seeds 3 and 5 in one process, and seed 5 alone."""
    root = tmp_path_factory.mktemp("seeds")
    group = [root / "s3", root / "s5"]
    code, _ = run_trainer(configs([3, 5]), group)
    assert code == 0
    code, _ = run_trainer(configs([5]), [root / "alone"])
    assert code == 0
    return root


def test_stack_take_and_mesh_shape():
    trees = [{"a": np.full(2, i), "b": (np.float32(i),)} for i in range(3)]
    stacked = stack(trees)
    assert stacked["a"].shape == (3, 2) and stacked["b"][0].shape == (3,)
    assert float(take(stacked, 2)["b"][0]) == 2.0
    assert take(stacked, [0, 2])["a"].tolist() == [[0, 0], [2, 2]]
    assert mesh_shape(1, 1, 16) == (1, 1)
    assert mesh_shape(4, 2, 16) == (2, 1)  # seeds spread first: no communication
    assert mesh_shape(1, 4, 16) == (1, 4)
    assert mesh_shape(3, 2, 16) == (1, 2)
    with pytest.raises(ConfigError, match=r"train.devices=4 .* does not divide train.batch=6"):
        mesh_shape(1, 4, 6)


@pytest.mark.slow
def test_each_seed_writes_a_complete_run_equal_to_the_single_seed_run(two_seeds):
    for name, seed in (("s3", 3), ("s5", 5)):
        logdir = two_seeds / name
        assert json.loads((logdir / "config.json").read_text())["train"]["seed"] == seed
        assert scores(logdir)["seed"] == str(seed) and scores(logdir)["xs"] == [208.0, STEPS]
        assert list((logdir / "episodes").glob("*.mcap"))
        assert list((logdir / "videos").glob("open_loop_*.mp4"))
        assert checkpoint.list_checkpoints(logdir / "checkpoints")[-1][0] == STEPS
    grouped, alone = train_records(two_seeds / "s5"), train_records(two_seeds / "alone")
    assert len(grouped) == len(alone) >= 2 and grouped[-1]["train/updates"] >= 5
    for a, b in zip(grouped, alone, strict=True):
        assert a.keys() == b.keys()
        for key in ("step", "train/updates", "train/episodes", "train/replay_steps"):
            assert a[key] == b[key], key
        losses = sorted(k for k in a if k.startswith(("train/wm/", "train/actor/",
                                                        "train/critic/", "train/imag/")))
        np.testing.assert_allclose([a[k] for k in losses], [b[k] for k in losses], rtol=1e-4,
                                   atol=1e-5, err_msg=f"step {a['step']}")
    assert scores(two_seeds / "s5")["ys"] == pytest.approx(scores(two_seeds / "alone")["ys"],
                                                           abs=1e-4)
    # the two seeds are different runs
    assert train_records(two_seeds / "s3")[-1]["train/wm/loss"] != grouped[-1]["train/wm/loss"]


@pytest.mark.slow
def test_resume_after_a_kill_between_two_seeds_saves_continues_from_their_common_step(
        two_seeds, tmp_path):
    for name in ("s3", "s5"):
        (tmp_path / name).mkdir()
        for item in ("checkpoints", "episodes"):
            subprocess.run(["cp", "-r", str(two_seeds / name / item), str(tmp_path / name)],
                           check=True)
        for item in ("config.json", "metrics.jsonl", "scores.jsonl", "eval_episodes.jsonl"):
            (tmp_path / name / item).write_bytes((two_seeds / name / item).read_bytes())
    # killed after seed 3 saved step 320 and before seed 5 did
    (tmp_path / "s5" / "checkpoints" / "ckpt-000000000320.ckpt").unlink()
    common = checkpoint.list_checkpoints(tmp_path / "s5" / "checkpoints")[-1][0]
    assert common < STEPS
    more = configs([3, 5], "train.steps=360")
    trainer = HostTrainer(more, [tmp_path / "s3", tmp_path / "s5"], progress=False,
                            out=lambda *_: None)
    try:
        assert trainer.env_steps == common
        assert trainer.describe().startswith(f"resuming from ckpt-{common:012d}.ckpt")
        assert trainer.run() == 0
    finally:
        trainer.close()
    for name in ("s3", "s5"):
        steps = [r["step"] for r in train_records(tmp_path / name)]
        assert steps == sorted(set(steps)) and steps[-1] > STEPS
        assert checkpoint.list_checkpoints(tmp_path / name / "checkpoints")[-1][0] >= 360


@pytest.mark.slow
def test_a_seeds_non_finite_update_stops_only_that_seed(tmp_path, capsys):
    """Seed 1's third update is NaN: it stops with its checkpoints of update <= 2 kept."""
    trainer = HostTrainer(configs([0, 1], "train.ckpt_every=1"), [tmp_path / "a", tmp_path / "b"],
                            progress=False, out=lambda *_: None)
    real_step = trainer.parallel.train_step

    def poisoned(state, batch, keys):
        state, metrics = real_step(state, batch, keys)
        if trainer.counters.updates == 2:
            metrics = dict(metrics, **{"wm/loss": metrics["wm/loss"].at[1].set(np.nan)})
        return state, metrics

    trainer.parallel.train_step = poisoned
    try:
        assert trainer.run() == 1
    finally:
        trainer.close()
    err = capsys.readouterr().err
    assert "seed 1: training stopped: non-finite metrics at update 3" in err
    assert "wm/loss=nan" in err and "the other seeds go on" in err
    assert checkpoint.list_checkpoints(tmp_path / "b" / "checkpoints")[-1][0] < STEPS
    last = restore_latest(tmp_path / "b" / "checkpoints", trainer.agent, jax.random.PRNGKey(1))
    assert last.meta["counters"]["updates"] == 2 and int(last.tree["agent"].step) == 2
    assert trainer.stopped == [1] and trainer.seeds == [0]
    assert scores(tmp_path / "a")["xs"][-1] == STEPS
    assert train_records(tmp_path / "a")[-1]["train/updates"] >= 5  # went on after update 3


def test_bad_seeds_and_devices_are_errors_naming_them(capsys, tmp_path):
    cases = {("--seeds", "0,0"): "distinct integers >= 0",
             ("--seeds", "1,-2"): "distinct integers >= 0",
             ("--seeds", "a,b"): "comma-separated integers",
             ("--seeds", "0,1", "--logdir", str(tmp_path)): "must contain {seed}",
             ("train.devices=9",): "train.devices=9: this process sees 1 device",
             ("train.devices=-1",): "valid: 0 (all) to 1",
             ("model.precision=float16",): "'float16'; valid: float32, bfloat16"}
    for args, message in cases.items():
        assert train.main(["--size", "debug", "--logdir", str(tmp_path / "{seed}"), *args]) == 2
        assert message in capsys.readouterr().err, args


SHARDED = textwrap.dedent("""
    import jax, numpy as np
    from tests.agents.dreamer.test_agent import make_agent, make_batch
    from vsgjax.loop.parallel import Parallel, stack
    agent = make_agent("vsg", False)
    assert len(jax.devices()) == 2
    states = [agent.init(jax.random.PRNGKey(seed)) for seed in (0, 1)]
    batches = [make_batch(agent.action_dim, False, seed) for seed in (0, 1)]
    keys = np.stack([jax.random.PRNGKey(10 + seed) for seed in (0, 1)])

    def update(seeds, devices):
        parallel = Parallel(agent, len(seeds), devices)
        state = parallel.put_state(stack([states[i] for i in seeds]))
        state, metrics = parallel.train_step(state, parallel.put_batch(
            [batches[i] for i in seeds]), keys[list(seeds)])
        return parallel.mesh_shape, jax.device_get((state.params, metrics))

    reference = {seeds: update(seeds, 1)[1] for seeds in ((0,), (0, 1))}
    for seeds, shape in (((0,), (1, 2)), ((0, 1), (2, 1))):
        got_shape, got = update(seeds, 2)
        assert got_shape == shape, got_shape
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(reference[seeds])):
            np.testing.assert_allclose(a, b, rtol=2e-4, atol=2e-5)
    print("sharded updates agree")
""")


@pytest.mark.slow
def test_sharded_update_equals_the_unsharded_one_on_two_forced_host_devices():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    result = subprocess.run([sys.executable, "-c", SHARDED], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "sharded updates agree" in result.stdout

