"""Latent dynamics models behind one interface
(:class:`vsgjax.agents.dreamer.dynamics.base.Dynamics`)."""

from vsgjax.agents.dreamer.cells import BERNOULLI_GATE, GateCell
from vsgjax.agents.dreamer.dynamics.base import (
    Dynamics,
    GatedRSSMState,
    RSSMState,
    SSMState,
    State,
    SVSGState,
)
from vsgjax.agents.dreamer.dynamics.rssm import RSSM
from vsgjax.agents.dreamer.dynamics.ssm import SSM
from vsgjax.agents.dreamer.dynamics.svsg import SVSG
from vsgjax.config import ModelConfig
from vsgjax.registry.agents import agent_entry, dreamer_models

_CLASSES = {cls.__name__: cls for cls in (RSSM, SVSG, SSM)}  # an entry's "dynamics" option


def make_dynamics(model_cfg: ModelConfig, gate: GateCell = BERNOULLI_GATE) -> Dynamics:
    """The dynamics of model ``model_cfg.name`` (its registry entry's ``dynamics`` option);
    ``gate`` is the sparse cell's gate of a gated model."""
    if model_cfg.name not in dreamer_models():
        raise ValueError(f"model {model_cfg.name!r} has no latent dynamics; valid: "
                         f"{', '.join(dreamer_models())}")
    return _CLASSES[agent_entry(model_cfg.name).option("dynamics")](model_cfg, gate)


__all__ = [
    "RSSM",
    "SSM",
    "SVSG",
    "Dynamics",
    "GatedRSSMState",
    "RSSMState",
    "SSMState",
    "SVSGState",
    "State",
    "make_dynamics",
]
