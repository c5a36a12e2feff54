"""Latent dynamics models behind one interface (:class:`vsgjax.model.dynamics.base.Dynamics`)."""

from vsgjax.config import MODELS, ModelConfig
from vsgjax.model.dynamics.base import (
    Dynamics,
    GatedRSSMState,
    RSSMState,
    SSMState,
    State,
    SVSGState,
)
from vsgjax.model.dynamics.rssm import RSSM
from vsgjax.model.dynamics.ssm import SSM
from vsgjax.model.dynamics.svsg import SVSG

_CLASSES = {"dreamerv1": RSSM, "dreamerv2": RSSM, "vsg": RSSM, "svsg": SVSG, "ssm": SSM}


def make_dynamics(model_cfg: ModelConfig) -> Dynamics:
    """The dynamics model named by ``model_cfg.name`` (one of ``vsgjax.config.MODELS``)."""
    if model_cfg.name not in _CLASSES:
        raise ValueError(f"unknown model {model_cfg.name!r}; valid: {', '.join(MODELS)}")
    return _CLASSES[model_cfg.name](model_cfg)


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
