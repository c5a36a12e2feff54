"""Latent distributions of the dynamics models, as pytrees (NamedTuples) over distrax.

Two families, both unbatched (a leading batch axis comes from ``jax.vmap``):

* :class:`Gaussian`: diagonal Normal over ``stoch`` dims; ``std = 2·σ(s/2) + min_std`` with the
  mean left unsquashed (DreamerV2's ``std_act="sigmoid2"``); reparameterised samples.
* :class:`Categorical`: ``stoch`` independent categoricals of ``classes`` classes each; samples are
  one-hot vectors with the straight-through gradient of the class probabilities.

Both give the KL per latent dimension (one value per Gaussian dim or per categorical variable),
so the world model can sum it, or mask it with gates first (SVSG).
:class:`LatentSpace` maps a dense layer's raw output to a distribution and back to flat vectors.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import distrax
import jax
import jax.numpy as jnp


class Gaussian(NamedTuple):
    """Diagonal Normal; ``mean`` and ``std`` are ``[stoch]``."""

    mean: jax.Array
    std: jax.Array

    def as_distrax(self) -> distrax.Normal:
        return distrax.Normal(self.mean, self.std)

    def sample(self, key: jax.Array) -> jax.Array:
        """Reparameterised sample ``mean + std·ε``, ``[stoch]``."""
        return self.mean + self.std * jax.random.normal(key, self.mean.shape, self.mean.dtype)

    def mode(self) -> jax.Array:
        return self.mean

    def kl(self, other: Gaussian) -> jax.Array:
        """``KL(self ‖ other)`` per dimension, ``[stoch]``."""
        return self.as_distrax().kl_divergence(other.as_distrax())

    def entropy(self) -> jax.Array:
        """Entropy summed over dimensions (scalar)."""
        return self.as_distrax().entropy().sum()


class Categorical(NamedTuple):
    """``stoch`` independent categoricals; ``logits`` is ``[stoch, classes]``."""

    logits: jax.Array

    def as_distrax(self) -> distrax.Categorical:
        return distrax.Categorical(logits=self.logits)

    def sample(self, key: jax.Array) -> jax.Array:
        """One-hot sample ``[stoch, classes]``, straight-through w.r.t. the probabilities.

        Forward value is exactly one-hot; gradient is that of ``softmax(logits)``
        (``sample + probs - sg(probs)``, written so the forward pass adds an exact zero).
        """
        index = jax.random.categorical(key, self.logits, axis=-1)
        one_hot = jax.nn.one_hot(index, self.logits.shape[-1], dtype=self.logits.dtype)
        probs = jax.nn.softmax(self.logits, axis=-1)
        return one_hot + (probs - jax.lax.stop_gradient(probs))

    def mode(self) -> jax.Array:
        index = jnp.argmax(self.logits, axis=-1)
        return jax.nn.one_hot(index, self.logits.shape[-1], dtype=self.logits.dtype)

    def kl(self, other: Categorical) -> jax.Array:
        """``KL(self ‖ other)`` per categorical variable, ``[stoch]``."""
        return self.as_distrax().kl_divergence(other.as_distrax())

    def entropy(self) -> jax.Array:
        """Entropy summed over variables (scalar)."""
        return self.as_distrax().entropy().sum()


Latent = Gaussian | Categorical


def gaussian_std(raw_std: jax.Array, min_std: float) -> jax.Array:
    """``2·σ(s/2) + min_std``: std in ``(min_std, 2 + min_std)``, equal to ``1 + min_std`` at 0."""
    return 2.0 * jax.nn.sigmoid(raw_std / 2.0) + min_std


@dataclass(frozen=True)
class LatentSpace:
    """Shape of a stochastic latent: Gaussian if ``classes == 0``, else ``stoch × classes``."""

    stoch: int
    classes: int
    min_std: float = 0.1

    def __post_init__(self):
        if self.stoch <= 0:
            raise ValueError(f"latent stoch must be positive, got {self.stoch}")
        if self.classes < 0 or self.classes == 1:
            raise ValueError(f"latent classes must be 0 (Gaussian) or >= 2, got {self.classes}")

    @property
    def discrete(self) -> bool:
        return self.classes > 0

    @property
    def stats_dim(self) -> int:
        """Width of the raw layer output that :meth:`from_raw` consumes."""
        return self.stoch * self.classes if self.discrete else 2 * self.stoch

    @property
    def flat_dim(self) -> int:
        """Size of a flattened sample."""
        return self.stoch * self.classes if self.discrete else self.stoch

    def from_raw(self, raw: jax.Array) -> Latent:
        """``[stats_dim]`` layer output -> distribution."""
        if self.discrete:
            return Categorical(raw.reshape(self.stoch, self.classes))
        mean, raw_std = jnp.split(raw, 2, axis=-1)
        return Gaussian(mean, gaussian_std(raw_std, self.min_std))

    def zeros(self) -> tuple[jax.Array, Latent]:
        """All-zero sample and distribution parameters (the initial state)."""
        if self.discrete:
            shape = (self.stoch, self.classes)
            return jnp.zeros(shape), Categorical(jnp.zeros(shape))
        return jnp.zeros(self.stoch), Gaussian(jnp.zeros(self.stoch), jnp.zeros(self.stoch))

    def flatten(self, sample: jax.Array) -> jax.Array:
        """Sample ``[..., stoch]`` or ``[..., stoch, classes]`` -> ``[..., flat_dim]``."""
        if self.discrete:
            return sample.reshape(*sample.shape[:-2], self.flat_dim)
        return sample
