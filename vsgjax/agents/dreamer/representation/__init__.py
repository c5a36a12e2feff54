"""What the world model's latent states learn to represent of the observation: the
representation component, chosen by the registry entry's ``representation`` option.

* ``reconstruction`` (:class:`~.reconstruction.Reconstruction`, the default): decoders, and
  the observation's Gaussian log-likelihood ``-ln p(x|s)`` in the loss;
* ``prototypes`` (:class:`~.prototypes.Prototypes`, DreamerPro's): no decoder; prototype
  losses on two augmented views of the batch, with EMA target networks.

The world model keeps the encoder, the dynamics and the reward (+ discount) heads, and calls
its component (:class:`Representation`) for everything the two differ in: their parameters,
EMA targets, the views a batch is trained on, the per-step terms, the losses and metrics, and
decoding. ``decodes`` answers whether states can be drawn as observations (open-loop
observation errors and videos exist only then).
"""

from __future__ import annotations

from vsgjax.agents.dreamer.representation.interface import Representation
from vsgjax.agents.dreamer.representation.prototypes import Prototypes
from vsgjax.agents.dreamer.representation.reconstruction import Reconstruction
from vsgjax.config import Config
from vsgjax.observations import ObsSpec
from vsgjax.registry.agents import agent_entry

RECONSTRUCTION, PROTOTYPES = "reconstruction", "prototypes"  # a registry entry's representation
COMPONENTS = {RECONSTRUCTION: Reconstruction, PROTOTYPES: Prototypes}

__all__ = ["COMPONENTS", "PROTOTYPES", "RECONSTRUCTION", "Prototypes", "Reconstruction",
           "Representation", "build_representation"]


def build_representation(config: Config, obs_shape: ObsSpec, embed_size: int) -> Representation:
    """The representation the registry entry of ``config``'s model names."""
    model = config.agent
    kind = agent_entry(model).option("representation", RECONSTRUCTION)
    if kind not in COMPONENTS:
        raise ValueError(f"model {model!r} names representation {kind!r}; known: "
                         f"{', '.join(COMPONENTS)}")
    return COMPONENTS[kind](config, obs_shape, embed_size, model)
