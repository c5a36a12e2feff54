"""Checkpoints: round trip, keep-last-N, corrupt fallback, target mismatch."""


import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from vsgjax.data import checkpoint
from vsgjax.data.checkpoint import CheckpointMismatchError


def make_state(seed=0):
    """A training-state-like pytree: params, an optax state (NamedTuples), keys, a counter."""
    key = jax.random.PRNGKey(seed)
    params = {
        "encoder": {"w": jax.random.normal(key, (3, 4)), "b": jnp.zeros(4)},
        "head": [jnp.arange(5, dtype=jnp.int32), np.full((2, 2), seed, np.float64)],
    }
    return {
        "params": params,
        "opt": optax.adam(1e-3).init(params),
        "key": jax.random.fold_in(key, 1),
        "updates": seed + 7,
    }


def assert_trees_equal(actual, expected):
    assert jax.tree.structure(actual) == jax.tree.structure(expected)
    for a, e in zip(jax.tree.leaves(actual), jax.tree.leaves(expected), strict=True):
        assert type(a) is type(e) or (isinstance(a, jax.Array) and isinstance(e, jax.Array))
        assert np.asarray(a).dtype == np.asarray(e).dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(e))


def test_round_trip_restores_tree_meta_and_rng(tmp_path):
    state = make_state(seed=3)
    rng = np.random.default_rng(5)
    rng.random(10)
    meta = {"env_steps": 1234, "rng": checkpoint.rng_state(rng)}
    path = checkpoint.save(tmp_path, 40, state, meta)
    assert path == tmp_path / "ckpt-000000000040.ckpt" and checkpoint.latest(tmp_path) == path

    restored = checkpoint.restore(tmp_path, make_state(seed=0))
    assert restored.step == 40 and restored.path == path
    assert_trees_equal(restored.tree, state)
    assert isinstance(restored.tree["opt"][0], optax.ScaleByAdamState)
    assert restored.meta["env_steps"] == 1234
    resumed = checkpoint.rng_from_state(restored.meta["rng"])
    np.testing.assert_array_equal(resumed.random(4), rng.random(4))


def test_keeps_the_last_n_checkpoints(tmp_path):
    for step in [10, 20, 30, 40, 50]:
        checkpoint.save(tmp_path, step, make_state(step), keep=2)
    assert [step for step, _ in checkpoint.list_checkpoints(tmp_path)] == [40, 50]
    assert checkpoint.latest(tmp_path).name == "ckpt-000000000050.ckpt"
    assert checkpoint.restore(tmp_path, make_state()).tree["updates"] == 57


@pytest.mark.parametrize("damage", ["truncate", "garbage", "flip_byte"])
def test_corrupt_latest_falls_back_to_previous_with_warning(tmp_path, damage):
    checkpoint.save(tmp_path, 1, make_state(1))
    latest = checkpoint.save(tmp_path, 2, make_state(2))
    data = latest.read_bytes()
    latest.write_bytes({
        "truncate": data[: len(data) - 10],
        "garbage": b"\x00garbage" * 100,
        "flip_byte": data[:-20] + bytes([data[-20] ^ 1]) + data[-19:],
    }[damage])
    with pytest.warns(UserWarning, match=latest.name):
        restored = checkpoint.restore(tmp_path, make_state())
    assert restored.step == 1
    assert_trees_equal(restored.tree, make_state(1))


def test_saving_after_a_fallback_removes_the_abandoned_newer_checkpoint(tmp_path):
    for step in [10, 20, 30]:
        checkpoint.save(tmp_path, step, make_state(step), keep=2)
    checkpoint.checkpoint_path(tmp_path, 30).write_bytes(b"corrupt")
    with pytest.warns(UserWarning, match="ckpt-000000000030"):
        assert checkpoint.restore(tmp_path, make_state()).step == 20
    checkpoint.save(tmp_path, 25, make_state(25), keep=2)
    assert [step for step, _ in checkpoint.list_checkpoints(tmp_path)] == [20, 25]


def test_no_checkpoint_and_leftover_temp_files_give_none(tmp_path):
    assert checkpoint.restore(tmp_path / "missing", make_state()) is None
    (tmp_path / ".ckpt-000000000009.ckpt.abc123.tmp").write_bytes(b"partial")
    assert checkpoint.latest(tmp_path) is None
    assert checkpoint.restore(tmp_path, make_state()) is None


def test_target_mismatch_is_an_error_not_a_fallback(tmp_path):
    checkpoint.save(tmp_path, 1, make_state())
    wider = make_state()
    wider["params"]["encoder"]["b"] = jnp.zeros(5)
    with pytest.raises(CheckpointMismatchError, match=r"\['params'\]\['encoder'\]\['b'\].*\[4\]"):
        checkpoint.restore(tmp_path, wider)
    renamed = make_state()
    renamed["extra"] = jnp.zeros(1)
    with pytest.raises(CheckpointMismatchError,
                       match=r"checkpoint .*ckpt-000000000001\.ckpt does not fit this run \(its "
                             r"tree is not this run's: 15 saved leaves, 16 wanted; leaf 0 is "
                             r"\['key'\], wanted \['extra'\]\); is it another run's\?"):
        checkpoint.restore(tmp_path, renamed)


def test_the_meta_reads_without_decoding_the_arrays(tmp_path):
    meta = {"counters": {"updates": 3}, "config": {"train": {"seed": 1}}}
    path = checkpoint.save(tmp_path, 1, make_state(), meta)
    assert checkpoint.read_meta(path) == meta
    path.write_bytes(path.read_bytes()[:-1])
    with pytest.raises(checkpoint.CorruptCheckpointError, match="payload has"):
        checkpoint.read_meta(path)


def test_typed_keys_and_non_json_meta_are_rejected(tmp_path):
    with pytest.raises(TypeError, match="key_data"):
        checkpoint.save(tmp_path, 0, {"key": jax.random.key(0)})
    with pytest.raises(TypeError):
        checkpoint.save(tmp_path, 0, make_state(), {"rng": np.random.default_rng(0)})
    assert checkpoint.list_checkpoints(tmp_path) == []


def test_a_partial_target_reads_only_its_subtrees(tmp_path):
    state = make_state()
    checkpoint.save(tmp_path, 1, state)
    part = dict(state, opt=None, updates=None)  # None: a subtree left out
    restored = checkpoint.restore(tmp_path, part, partial=True)
    assert_trees_equal(restored.tree, part)
    with pytest.raises(CheckpointMismatchError, match=r"1 wanted; leaf 0 is none, wanted "
                                                      r"\['extra'\]"):
        checkpoint.restore(tmp_path, {"extra": jnp.zeros(1)}, partial=True)
