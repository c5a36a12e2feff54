"""DrQ-v2's settings: its config section ``drq`` as a frozen dataclass and its valid ranges.

Its registry entry names this module as its ``settings`` (:mod:`vsgjax.registry.agents`);
:func:`vsgjax.config.config_class` builds DrQ-v2's run config from it.
"""

from __future__ import annotations

from dataclasses import dataclass

from vsgjax.config.checks import AT_LEAST_0, AT_LEAST_1, POSITIVE, UNIT


@dataclass(frozen=True)
class DrQConfig:
    """DrQ-v2, the model-free baseline (facebookresearch/drqv2's ``drqv2.py`` and ``cfgs/``)."""

    feature_dim: int = 50  # the trunk: Linear(repr, 50) -> LayerNorm -> tanh
    hidden: int = 1024  # actor and twin-Q MLP widths
    cnn_depth: int = 32  # channels of the 4 conv layers (pixel observations only)
    frame_stack: int = 3  # frames stacked along channels (pixel observations only)
    nstep: int = 3  # n of the n-step return
    gamma: float = 0.99
    tau: float = 0.01  # Polyak rate of the target critic
    lr: float = 1e-4  # Adam, for encoder, actor and critic
    std_start: float = 1.0  # exploration std: linear from std_start ...
    std_end: float = 0.1  # ... to std_end ...
    std_steps: int = 500_000  # ... over this many agent steps (the task's horizon)
    std_clip: float = 0.3  # the target's and the actor loss's noise clip
    shift_pad: int = 4  # random-shift augmentation: edge-pad by this many pixels, crop back


SECTIONS = {"drq": DrQConfig}
RANGES = {
    "drq.feature_dim": AT_LEAST_1, "drq.hidden": AT_LEAST_1, "drq.cnn_depth": AT_LEAST_1,
    "drq.frame_stack": AT_LEAST_1, "drq.nstep": AT_LEAST_1, "drq.gamma": UNIT, "drq.tau": UNIT,
    "drq.lr": POSITIVE, "drq.std_start": AT_LEAST_0, "drq.std_end": AT_LEAST_0,
    "drq.std_steps": AT_LEAST_1, "drq.std_clip": AT_LEAST_0, "drq.shift_pad": AT_LEAST_0,
}

