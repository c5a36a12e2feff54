"""``vsgjax.load``, ``imagine`` from a trained run's params, ``experiments.rollouts`` and the
``experiments/notebooks/imagine.ipynb`` notebook, on one tiny trained run (debug size, CPU)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vsgjax
from experiments import rollouts
from tests.support.subprocess_env import subprocess_env
from vsgjax.agents.dreamer import api, open_loop
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.agents.dreamer.gate_statistics import gate_statistics
from vsgjax.config import make_config, to_dict
from vsgjax.data import checkpoint
from vsgjax.loop.run_state import checkpoint_tree

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOK = ROOT / "experiments" / "notebooks" / "imagine.ipynb"
TRAIN = ["--task", "bbs_basic", "--model", "vsg", "--size", "debug", "--seed", "0",
         "--no-progress", "env.time_limit=200", "train.steps=600"]  # 52-step episodes


@pytest.fixture(scope="module")
def logdir(tmp_path_factory) -> Path:
    """A finished tiny VSG run: 600 env steps, a checkpoint at 600, two stored episodes."""
    root = tmp_path_factory.mktemp("load_rollouts")
    env = subprocess_env()
    run_dir = root / "run"
    result = subprocess.run([sys.executable, "-m", "vsgjax.train", *TRAIN, "--logdir",
                             str(run_dir)], cwd=ROOT, env=env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    return run_dir


@pytest.fixture(scope="module")
def run(logdir):
    return vsgjax.load(logdir)


@pytest.fixture(scope="module")
def start(run):
    """The posterior after the newest episode's first 15 frames."""
    posts = run.observe(run.episode(-1))
    return jax.tree.map(lambda x: x[14], posts)


# --- fast -----------------------------------------------------------------------------------


def test_bad_paths_raise_file_not_found_naming_the_path(tmp_path):
    missing = tmp_path / "no_such_run"
    with pytest.raises(FileNotFoundError, match="no_such_run"):
        vsgjax.load(missing)
    assert not missing.exists()  # loading creates nothing
    empty = tmp_path / "not_a_run"
    empty.mkdir()
    with pytest.raises(FileNotFoundError, match="not_a_run.*config.json|config.json.*not_a_run"):
        vsgjax.load(empty)
    fresh = tmp_path / "fresh_run"
    fresh.mkdir()
    (fresh / "config.json").write_text(json.dumps(to_dict(make_config("bbs_basic", "vsg",
                                                                      "debug"))))
    with pytest.raises(FileNotFoundError, match="fresh_run.*checkpoint|checkpoint.*fresh_run"):
        vsgjax.load(fresh)
    assert rollouts.main([str(missing)]) == 2


def test_trained_params_are_a_pytree_with_the_config_as_static_data():
    config = make_config("bbs_basic", "vsg", "debug")
    params = api.TrainedParams({"a": np.ones(2)}, {"b": np.zeros(3)}, None, config, 2, False)
    leaves, treedef = jax.tree_util.tree_flatten(params)
    assert len(leaves) == 2
    again = jax.tree_util.tree_unflatten(treedef, leaves)
    assert again.config is config and again.action_dim == 2 and again.critic is None
    doubled = jax.tree.map(lambda x: x + 1, params)
    assert isinstance(doubled, api.TrainedParams) and doubled["actor"]["b"].tolist() == [1] * 3
    assert vsgjax.TrainedParams is api.TrainedParams


# --- on the trained run ---------------------------------------------------------------------


@pytest.mark.slow
def test_load_returns_config_params_and_episodes(run, logdir):
    assert run.config.agent == "vsg" and run.config.size == "debug"
    assert run.step == 600 and run.checkpoint.parent == logdir / "checkpoints"
    assert set(run.params.wm) >= {"encoder", "dynamics", "decoder", "reward"}
    assert run.params.actor is not None and run.params.critic is not None
    assert run.params.config == run.config and run.gated
    assert tuple(run.spec) == ((64, 64, 3), 2, False)
    episodes = run.episodes()
    assert len(episodes) == len(run.episode_paths()) >= 1
    assert all(len(e["image"]) >= 50 for e in episodes)
    assert len(run.episodes(limit=1)) == 1
    np.testing.assert_array_equal(run.episode(-1)["image"], episodes[-1]["image"])
    assert len(list(run.iter_episodes())) == len(episodes)
    with pytest.raises(IndexError, match="out of range"):
        run.episode(len(episodes))
    assert "bbs_basic" in repr(run) and "600" in repr(run)


@pytest.mark.slow
def test_observe_gives_posteriors_with_binary_gates(run):
    episode = run.episode(-1)
    posts, priors = run.observe(episode, priors=True)
    length = len(episode["image"])
    assert posts.deter.shape == priors.deter.shape == (length, run.config.model.deter)
    assert set(np.unique(np.asarray(posts.gate))) <= {0.0, 1.0}
    again = run.observe(episode)
    jax.tree.map(np.testing.assert_array_equal, posts, again)  # default key: deterministic
    batched = run.observe({k: v[None] for k, v in episode.items()})
    assert batched.deter.shape == (1, length, run.config.model.deter)


@pytest.mark.slow
def test_the_notebook_call_imagines_under_the_actor_deterministically(run, start):
    params = run.params
    out = vsgjax.imagine(params, start, H=15)
    again = vsgjax.imagine(params, start, H=15)
    jax.tree.map(np.testing.assert_array_equal, out, again)
    assert out["images"].shape == (15, 64, 64, 3) and out["images"].dtype == jnp.uint8
    assert out["rewards"].shape == out["discounts"].shape == (15,)
    actions = np.asarray(out["actions"])
    assert actions.shape == (15, 2) and np.abs(actions).max() <= 1 and np.abs(actions).min() > 0
    # the same as spelling everything out: config, PRNGKey(0), the actor's samples
    spelled = api.imagine(params.wm, start, 15, config=run.config, key=jax.random.PRNGKey(0),
                          policy=run.policy)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-5), out, spelled)
    # pure: the same under jit, with the params as a traced pytree
    jitted = jax.jit(lambda p, s: vsgjax.imagine(p, s, H=15))(params, start)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-5), out, jitted)
    other = vsgjax.imagine(params, start, H=15, key=jax.random.PRNGKey(1))
    assert not np.array_equal(other["actions"], out["actions"])
    # without an actor, or with action_dim: zero actions; recorded actions: open loop
    no_actor = dataclasses.replace(params, actor=None)
    assert not np.asarray(vsgjax.imagine(no_actor, start, H=4)["actions"]).any()
    assert not np.asarray(vsgjax.imagine(params, start, H=4, action_dim=2)["actions"]).any()
    recorded = run.episode(-1)["action"][15:19]
    np.testing.assert_array_equal(vsgjax.imagine(params, start, H=4, actions=recorded)["actions"],
                                  recorded)
    with pytest.raises(ValueError, match="config"):
        vsgjax.imagine(params, start, H=4, config=make_config("bbs_basic", "vsg", "small"))
    with pytest.raises(TypeError, match="config"):
        vsgjax.imagine(params.wm, start, H=4, action_dim=2)


@pytest.mark.slow
def test_loaded_run_statistics_equal_those_of_its_params(run):
    """``gate_statistics`` of a loaded run equals that of its world model's params."""
    episodes = run.episodes(limit=2)
    length = min(32, *(len(ep["is_first"]) for ep in episodes))
    batch = {k: np.stack([ep[k][:length] for ep in episodes]) for k in episodes[0]}
    key = jax.random.PRNGKey(1)
    loaded = gate_statistics(run.params, batch, key)
    direct = gate_statistics(run.params.wm, batch, key, config=run.config)
    for a, b in zip(jax.tree.leaves(loaded), jax.tree.leaves(direct), strict=True):
        np.testing.assert_array_equal(a, b)
    assert loaded.summary() == direct.summary()


@pytest.mark.slow
def test_rollout_data_is_the_papers_grid_with_gates_from_the_states(run):
    index, episode = rollouts.pick_episode(run, 50)
    key = jax.random.PRNGKey(3)
    data = rollouts.rollout_data(run, episode, key=key, episode_index=index)
    assert data.frames.shape == (6, 50, 64, 64, 3) and data.frames.dtype == np.uint8
    np.testing.assert_array_equal(data.frames[0], episode["image"][:50])
    # the same frames as the run's open-loop video for the same key
    video = open_loop.open_loop_frames(run.config, run.params.wm, episode, key)
    np.testing.assert_array_equal(np.concatenate(list(data.frames), axis=2), video)
    assert data.gates.shape == (run.config.model.deter, 50)
    assert set(np.unique(data.gates)) <= {0.0, 1.0} and 0 < data.gates.mean() < 1
    assert data.gate_fraction.shape == (5, 50)
    np.testing.assert_allclose(data.gate_fraction[0], data.gates.mean(0))
    assert data.rewards.shape == (6, 50)
    with pytest.raises(ValueError, match="shorter"):
        rollouts.rollout_data(run, episode, context=15, horizon=100)
    with pytest.raises(IndexError, match="out of range"):
        rollouts.pick_episode(run, 50, index=99)


@pytest.mark.slow
def test_rollouts_command_writes_png_pdf_and_data(logdir, tmp_path, capsys):
    out = tmp_path / "figures"
    assert rollouts.main([str(logdir), "--out", str(out), "--episode", "-1", "--seed", "1"]) == 0
    printed = capsys.readouterr().out
    episode = len(list((logdir / "episodes").glob("*.mcap"))) - 1
    for name in (f"open_loop-ep{episode}", f"gates-ep{episode}"):
        assert (out / f"{name}.png").read_bytes()[:4] == b"\x89PNG", printed
        assert (out / f"{name}.pdf").read_bytes()[:5] == b"%PDF-"
    data = np.load(out / f"rollouts-ep{episode}.npz")
    assert data["frames"].shape == (6, 50, 64, 64, 3) and data["gates"].shape == (32, 50)


@pytest.mark.slow
def test_a_model_without_gates_gets_the_grid_and_a_note(logdir, tmp_path):
    """An untrained DreamerV2 run dir (fresh params, the VSG run's episodes): no heatmap."""
    config = make_config("bbs_basic", "dreamerv2", "debug")
    other = tmp_path / "dreamerv2"
    (other / "episodes").mkdir(parents=True)
    (other / "config.json").write_text(json.dumps(to_dict(config)))
    newest = sorted((logdir / "episodes").glob("*.mcap"))[-1]
    (other / "episodes" / newest.name).write_bytes(newest.read_bytes())
    key = jax.random.PRNGKey(0)
    state = DreamerAgent(config, (64, 64, 3), 2, False).init(key)
    checkpoint.save(other / "checkpoints", 0, checkpoint_tree(state, key))
    notes = []
    data, written = rollouts.make_rollouts(other, tmp_path / "out", samples=2, say=notes.append)
    assert data.gates is None and data.frames.shape == (3, 50, 64, 64, 3)
    assert any("no gates" in note for note in notes)
    assert sorted(p.name for p in written) == ["open_loop-ep0.pdf", "open_loop-ep0.png",
                                               "rollouts-ep0.npz"]
    with pytest.raises(ValueError, match="no gates"):
        rollouts.draw_gates(data)


@pytest.mark.slow
def test_the_notebook_executes_on_the_run(logdir, monkeypatch):
    import nbformat
    from nbclient import NotebookClient

    notebook = nbformat.read(NOTEBOOK, as_version=4)
    assert all(not cell.get("outputs") for cell in notebook.cells if cell.cell_type == "code")
    assert any("vsgjax.imagine(params, state, H=15)" in cell.source for cell in notebook.cells)
    # as a user would: the run named relative to the folder Jupyter is started from ($PWD),
    # while the kernel runs in the notebook's folder
    monkeypatch.setenv("PWD", str(logdir.parent))
    monkeypatch.setenv("VSGJAX_RUN", logdir.name)
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    client = NotebookClient(notebook, kernel_name="python3", timeout=300,
                            resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute()
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    # frames, gates, gate statistics, rewards
    assert sum(o.output_type == "display_data" for o in outputs) == 4
    assert any("gates/open" in o.get("text", "") for o in outputs if o.output_type == "stream")
