"""What a run's checkpoint holds, and restoring the newest readable one into an agent's
structure: a host-loop run's ``{"agent", "key"}``, or a device-loop run's whole loop state."""

from __future__ import annotations

from pathlib import Path

import jax

from vsgjax.agents.interface import Agent
from vsgjax.data import checkpoint
from vsgjax.loop.device_program import LoopState
from vsgjax.loop.which_loop import resolve_loop


def checkpoint_tree(state, key: jax.Array) -> dict:
    """What a checkpoint holds as arrays: the whole agent state and the training PRNG key."""
    return {"agent": state, "key": key}


def restore_latest(ckpt_dir: Path, agent: Agent, key: jax.Array,
                   max_step: int | None = None) -> checkpoint.Checkpoint | None:
    """The newest readable checkpoint (of a step up to ``max_step``, if given) filled into the
    agent's structure, or None. A device-loop run's checkpoint holds its whole loop state
    (agent, device replay, key): its agent and key are read alone, without the replay, and
    given as ``{"agent", "key"}`` too."""
    if resolve_loop(agent.config) == "device":
        return _restore_device_run(ckpt_dir, agent, key, max_step)
    target = checkpoint_tree(jax.eval_shape(agent.init, key), key)  # shapes only, no compute
    return checkpoint.restore(ckpt_dir, target, max_step)


def _restore_device_run(ckpt_dir: Path, agent: Agent, key: jax.Array,
                        max_step: int | None) -> checkpoint.Checkpoint | None:
    """The loop state's agent and key, filled into the agent's structure: the replay's
    structure is the device program's, which reading the parameters does not need."""
    template = LoopState(jax.eval_shape(agent.init, key), None, key)
    restored = checkpoint.restore(ckpt_dir, {"loop": template}, max_step, partial=True)
    if restored is None:
        return None
    state = restored.tree["loop"]
    return restored._replace(tree=checkpoint_tree(state.agent, state.key))
