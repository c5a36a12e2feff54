"""Restoring a run's agent from its checkpoint (:mod:`vsgjax.loop.run_state`)."""

import jax
import numpy as np

from vsgjax.agents import make_agent
from vsgjax.config import make_config
from vsgjax.data import checkpoint
from vsgjax.envs import EnvSpec
from vsgjax.loop import device_program
from vsgjax.loop.run_state import restore_latest
from vsgjax.loop.which_loop import resolve_loop
from vsgjax.observations import ObsSpec


def test_a_device_run_restores_without_a_device_program_or_task(tmp_path, monkeypatch):
    """A device-loop checkpoint holds the whole loop state; its agent and key are read into
    the agent's structure alone, the replay skipped, no device program or task built."""
    config = make_config("mjx_walker_walk", "dreamerv2", "debug")
    assert resolve_loop(config) == "device"
    agent = make_agent(config, EnvSpec(ObsSpec.from_dict({"vector": (5,)}), 2, False))
    key = jax.random.PRNGKey(3)
    shapes = jax.eval_shape(agent.init, key)
    leaves, treedef = jax.tree.flatten(shapes)
    agent_state = treedef.unflatten(
        [np.full(leaf.shape, i, leaf.dtype) for i, leaf in enumerate(leaves)])
    replay = {"vector": np.zeros((4, 3, 5), np.float32), "filled": np.int32(2)}
    loop_key = jax.random.fold_in(key, 1)
    checkpoint.save(tmp_path, 7, {"loop": device_program.LoopState(agent_state, replay,
                                                                   loop_key)})

    def refuse(*args, **kwargs):
        raise AssertionError("restoring the parameters built a device program")

    monkeypatch.setattr(device_program.DeviceProgram, "__init__", refuse)
    restored = restore_latest(tmp_path, agent, key)
    assert restored.step == 7 and set(restored.tree) == {"agent", "key"}
    np.testing.assert_array_equal(restored.tree["key"], loop_key)
    got = jax.tree.leaves(restored.tree["agent"])
    assert len(got) == len(leaves)
    for i, leaf in enumerate(got):
        np.testing.assert_array_equal(leaf, np.full(leaves[i].shape, i, leaves[i].dtype))
