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
from vsgjax.agents.dreamer.settings import ModelConfig
from vsgjax.registry.agents import agent_entry, dreamer_models

_CLASSES = {cls.__name__: cls for cls in (RSSM, SVSG, SSM)}  # an entry's "dynamics" option


def make_dynamics(model_cfg: ModelConfig, name: str, precision: str = "float32",
                  gate: GateCell = BERNOULLI_GATE) -> Dynamics:
    """The dynamics of model ``name`` (its registry entry's ``dynamics`` option) with the
    ``model`` section ``model_cfg``, matmuls in ``precision``; ``gate`` is the sparse cell's
    gate of a gated model."""
    if name not in dreamer_models():
        raise ValueError(f"model {name!r} has no latent dynamics; valid: "
                         f"{', '.join(dreamer_models())}")
    return _CLASSES[agent_entry(name).option("dynamics")](model_cfg, name, precision, gate)


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
