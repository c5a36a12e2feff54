"""The agents: the interface they share (:mod:`~vsgjax.agents.interface`), one package per
implementation (``dreamer/``: the Dreamer family; ``drqv2/``: DrQ-v2; which models each one
implements is :mod:`vsgjax.registry.agents`' to say, ``dreamer_models()`` for the first), and
:func:`make_agent`, which builds the agent a config names through the registry
(:mod:`vsgjax.registry.agents`)."""

from __future__ import annotations

from vsgjax.config import Config
from vsgjax.registry import resolve
from vsgjax.registry.agents import agent_entry


def make_agent(config: Config, spec):
    """The agent of ``config.agent`` for an env ``spec`` (``.obs``, ``.action_dim``,
    ``.discrete``); the only place an agent is constructed outside its own package."""
    agent_class = resolve(agent_entry(config.agent).implementation)
    return agent_class(config, spec.obs, spec.action_dim, spec.discrete)
