"""The world model: encoder, latent dynamics, representation component and heads, and its
loss.

    L = L_repr - reward_scale ln p(r|s) [- discount_scale ln p(γ|s)] + L_kl + L_gate

``L_repr`` is the representation component's (:mod:`vsgjax.agents.dreamer.representation`,
chosen by the registry entry): ``-ln p(x|s)`` of the decoders (``reconstruction``), or
DreamerPro's prototype losses over two augmented views of the batch with EMA targets kept by
the agent (``prototypes``).

(the discount head's target is γ·(1 − is_terminal) with ``ac.alignment=release``, as the
release; 1 − is_terminal with ``next_state``)

    L_kl = kl_scale [ (1 - balance) max(mean KL(q || sg p), free)
                      +     balance  max(mean KL(sg q || p), free) ]

The KL of one step is summed over the latent dimensions (for SVSG with ``kl_masked`` each
dimension's KL is first multiplied by the straight-through gate sample, so closed units cost
nothing and the mask passes gradient into the gate probability); the free nats clamp the mean
over the whole batch, not each step. ``L_gate`` is the gate objective ``wm.gate_objective``
of :mod:`vsgjax.agents.dreamer.gate_objectives` (the release's: the sparsity loss of
:mod:`vsgjax.agents.dreamer.gates`). Log-likelihoods are summed over pixels (vector entries) and
averaged over batch and time.

The observations x are the keys of an :class:`~vsgjax.observations.ObsSpec` (``wm.encoder``):
the 64x64 ``image`` goes through the CNN, the vector keys (concatenated in key order) through
an MLP; the embedding is the two concatenated (image first). The dynamics see only the embedding.

All per-step terms are computed per sequence (:meth:`WorldModel.sequence_terms`, unbatched) and
vmapped over the batch with one PRNG key per sequence. The networks' matmuls run in
``model.precision`` (:mod:`vsgjax.agents.precision`); the loss and all its terms are float32.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer import gate_objectives, gates
from vsgjax.agents.dreamer.cells import open_probability
from vsgjax.agents.dreamer.dynamics import make_dynamics
from vsgjax.agents.dreamer.networks import (
    DECODER_KERNELS,
    HEAD_PREFIX,
    MLP,
    ConvEncoder,
    MLPEncoder,
    bernoulli_log_prob,
    embed_dim,
    image_to_float,
    normal_log_prob,
)
from vsgjax.agents.dreamer.representation import Representation, build_representation
from vsgjax.agents.precision import compute_dtype
from vsgjax.config import Config, ConfigError
from vsgjax.observations import IMAGE_KEY, ObsSpec, obs_spec

sg = jax.lax.stop_gradient
IMAGE_SIZE = 64  # the CNN encodes and decodes 64x64 images


def per_step_kl(dyn, lhs, rhs, mask: jax.Array | None = None) -> jax.Array:
    """KL(lhs || rhs) of stacked states [T, ...] -> [T], summed over latent dimensions.

    ``mask`` [T, D] (the straight-through gate sample) multiplies the per-dimension KL first.
    """
    kl = jax.vmap(dyn.kl)(lhs, rhs)
    if mask is not None:
        kl = kl * mask
    return kl.reshape(kl.shape[0], -1).sum(-1)


def balanced_kl_loss(kl_rep: jax.Array, kl_dyn: jax.Array, scale: float, balance: float,
                     free: float) -> jax.Array:
    """``scale·[(1-balance)·max(kl_rep, free) + balance·max(kl_dyn, free)]``.

    ``kl_rep`` = mean KL(q ‖ sg p) (trains the posterior), ``kl_dyn`` = mean KL(sg q ‖ p)
    (trains the prior); both are batch means, so the free nats clamp the average KL.
    """
    return scale * ((1.0 - balance) * jnp.maximum(kl_rep, free)
                    + balance * jnp.maximum(kl_dyn, free))


def check_encoders(spec: ObsSpec, encoder: str) -> None:
    """Raise unless ``wm.encoder`` can encode every key of ``spec``.

    ``auto``: the CNN for the image, the MLP for the vector keys; ``cnn`` / ``mlp`` insist on
    image-only / vector-only observations. The CNN encodes one image, ``image``, of 64x64.
    """
    images, vectors = spec.image_keys, spec.vector_keys
    if images and images != (IMAGE_KEY,):
        raise ValueError(f"the CNN encodes one image, under key {IMAGE_KEY!r}; the observation "
                         f"spec has image keys {list(images)}")
    if images and spec.shapes[IMAGE_KEY][:2] != (IMAGE_SIZE, IMAGE_SIZE):
        raise ValueError(f"the CNN encodes {IMAGE_SIZE}x{IMAGE_SIZE} images: observation "
                         f"{IMAGE_KEY!r} has shape {spec.shapes[IMAGE_KEY]}, want "
                         f"({IMAGE_SIZE}, {IMAGE_SIZE}, C)")
    wrong = {"cnn": ("vector", vectors), "mlp": ("image", images)}.get(encoder)
    if wrong and wrong[1]:
        kind, keys = wrong
        named = ", ".join(f"{key!r} {spec.shapes[key]}" for key in keys)
        raise ConfigError(f"wm.encoder={encoder} cannot encode the {kind} keys of the "
                          f"observation spec ({named}); use wm.encoder=auto (CNN for the "
                          f"image, MLP for vectors)")


def obs_spec_of(params: dict) -> ObsSpec:
    """The observation spec world-model ``params`` were built for, read from the decoders (the
    encoder's first kernel without a decoder)."""
    shapes = {}
    if "decoder" in params:
        channels = params["decoder"][f"ConvTranspose2_{len(DECODER_KERNELS) - 1}"]["bias"]
        shapes[IMAGE_KEY] = (IMAGE_SIZE, IMAGE_SIZE, channels.shape[-1])
    elif "encoder" in params:
        channels = params["encoder"]["Conv2_0"]["kernel"].shape[-2]
        shapes[IMAGE_KEY] = (IMAGE_SIZE, IMAGE_SIZE, channels)
    for name, head in params.get("mlp_decoder", {}).items():
        if name.startswith(HEAD_PREFIX):
            shapes[name.removeprefix(HEAD_PREFIX)] = (head["bias"].shape[-1],)
    return ObsSpec.from_dict(shapes)


@dataclasses.dataclass(frozen=True)
class WorldModel:
    """Encoder, dynamics, representation, reward (+ discount) heads. Hashable: usable as a jit
    static.

    ``obs_shape``: an image shape ``(64, 64, C)`` (the spec ``{"image": (64, 64, C)}``), a
    ``{key: shape}`` dict or an :class:`~vsgjax.observations.ObsSpec`; stored as the ObsSpec.
    ``representation``: the component the registry entry names (decoders or prototypes), built
    from the other fields.
    """

    config: Config
    obs_shape: ObsSpec | Mapping[str, Sequence[int]] | Sequence[int] = (64, 64, 3)
    action_dim: int = 2
    representation: Representation = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self):
        spec = obs_spec(self.obs_shape)
        check_encoders(spec, self.config.wm.encoder)
        object.__setattr__(self, "obs_shape", spec)
        object.__setattr__(self, "representation",
                           build_representation(self.config, spec, self.embed_size))

    # --- modules ---------------------------------------------------------------------------

    @property
    def has_image(self) -> bool:
        return bool(self.obs_shape.image_keys)

    @property
    def vector_keys(self) -> tuple[str, ...]:
        return self.obs_shape.vector_keys

    @functools.cached_property
    def dynamics(self):
        return make_dynamics(self.config.model, self.config.agent, self.config.precision,
                             gate_objectives.gate_cell(self.config.wm))

    @property
    def dtype(self) -> jnp.dtype:
        """Compute dtype of every matmul and convolution (``model.precision``)."""
        return compute_dtype(self.config.precision)

    @property
    def encoder(self) -> ConvEncoder:
        return ConvEncoder(self.config.wm.cnn_depth, self.dtype)

    @property
    def mlp_encoder(self) -> MLPEncoder:
        return MLPEncoder(self.config.wm.mlp_layers, self.config.wm.mlp_units, self.dtype)

    @property
    def embed_size(self) -> int:
        """Size of the embedding: the CNN's, then the vector MLP's."""
        wm = self.config.wm
        size = embed_dim(wm.cnn_depth, IMAGE_SIZE) if self.has_image else 0
        if self.vector_keys:
            size += wm.mlp_units if wm.mlp_layers else self.obs_shape.vector_size
        return size

    @property
    def reward_head(self) -> MLP:
        return MLP(self.config.wm.reward_layers, self.config.wm.mlp_units, dtype=self.dtype)

    @property
    def discount_head(self) -> MLP:
        return MLP(self.config.wm.discount_layers, self.config.wm.mlp_units, dtype=self.dtype)

    # --- parameters --------------------------------------------------------------------------

    def init(self, key: jax.Array) -> dict:
        """Parameters ``{[encoder,] [mlp_encoder,] dynamics, reward[, discount]}`` and the
        representation's (plain nested dicts): the CNN with an image, the MLP with vector keys;
        the decoders ``decoder`` / ``mlp_decoder``, or prototypes ``proto``.

        Pure; wrap in ``jax.jit`` (as :func:`vsgjax.agents.dreamer.api.init` does) to compile
        the many
        initialisers into one program instead of running them op by op.
        """
        k_enc, k_dyn, k_dec, k_rew, k_dis = jax.random.split(key, 5)
        # lazy_init: only the parameter initialisers run, not the modules' forward passes.
        feat = jax.ShapeDtypeStruct((self.dynamics.feat_dim,), jnp.float32)
        params = {}
        if self.has_image:
            image = jax.ShapeDtypeStruct(self.obs_shape.shapes[IMAGE_KEY], jnp.float32)
            params["encoder"] = self.encoder.lazy_init(k_enc, image)["params"]
        if self.vector_keys:
            vector = jax.ShapeDtypeStruct((self.obs_shape.vector_size,), jnp.float32)
            params["mlp_encoder"] = self.mlp_encoder.lazy_init(
                jax.random.fold_in(k_enc, 1), vector)["params"]
        params.update(self.representation.init(k_dec, feat))
        params["dynamics"] = self.dynamics.init(k_dyn, self.embed_size, self.action_dim)
        params["reward"] = self.reward_head.lazy_init(k_rew, feat)["params"]
        if self.config.wm.discount_head:
            params["discount"] = self.discount_head.lazy_init(k_dis, feat)["params"]
        return params

    # --- pieces the actor-critic and notebooks use (any leading batch dims) -----------------

    def encode(self, params: dict, obs: Mapping | jax.Array) -> jax.Array:
        """Observations -> embeddings [..., E] (:attr:`embed_size`).

        ``obs``: a dict with the spec's keys and any leading dims (other keys ignored): the
        image uint8 [..., 64, 64, C] (or already scaled float), vectors float [..., D]. A bare
        array is the image of an image-only spec.
        """
        if not isinstance(obs, Mapping):
            obs = {IMAGE_KEY: obs}
        self.obs_shape.check(obs)
        parts = []
        if self.has_image:
            parts.append(self.encoder.apply({"params": params["encoder"]},
                                            image_to_float(obs[IMAGE_KEY])))
        if self.vector_keys:
            parts.append(self.mlp_encoder.apply({"params": params["mlp_encoder"]},
                                                self.vector_input(obs)))
        return parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=-1)

    def vector_input(self, obs: Mapping) -> jax.Array:
        """The vector keys of ``obs`` as float32, concatenated in key order: [..., D]."""
        return jnp.concatenate([obs[key].astype(jnp.float32) for key in self.vector_keys], -1)

    def reward_mean(self, params: dict, feat: jax.Array) -> jax.Array:
        """Mean of the reward Normal(σ=1) (in tanh units when ``reward_tanh``)."""
        return self.reward_head.apply({"params": params["reward"]}, feat)

    def discount_logits(self, params: dict, feat: jax.Array) -> jax.Array:
        return self.discount_head.apply({"params": params["discount"]}, feat)

    @property
    def discount_head_includes_gamma(self) -> bool:
        """Whether the discount head is trained on γ·(1 − is_terminal) and used as it is (the
        release, ``ac.alignment=release``) rather than trained on 1 − is_terminal and scaled
        by γ (``next_state``)."""
        return self.config.ac.alignment == "release"

    def discount_target(self, is_terminal: jax.Array) -> jax.Array:
        """The discount head's Bernoulli target: (γ·)(1 − is_terminal)."""
        continuing = 1.0 - is_terminal.astype(jnp.float32)
        return self.config.ac.gamma * continuing if self.discount_head_includes_gamma \
            else continuing

    def discount(self, params: dict, feat: jax.Array) -> jax.Array:
        """The predicted discount d(s) behaviour learning uses: γ without a discount head;
        else the head's Bernoulli mean, times γ unless the head was trained to include it."""
        gamma = self.config.ac.gamma
        if not self.config.wm.discount_head:
            return jnp.full(feat.shape[:-1], gamma, feat.dtype)
        prob = jax.nn.sigmoid(self.discount_logits(params, feat))
        return prob if self.discount_head_includes_gamma else gamma * prob

    def observe(self, params: dict, seq: dict, key: jax.Array, embeds: jax.Array | None = None):
        """Posterior and prior states [T, ...] of one sequence (dict of [T, ...] arrays);
        ``embeds`` [T, E] when the caller has encoded it already."""
        embeds = self.encode(params, seq) if embeds is None else embeds
        return self.dynamics.observe(params["dynamics"], embeds, seq["action"].astype(jnp.float32),
                                     seq["is_first"], key)

    # --- loss --------------------------------------------------------------------------------

    def sequence_terms(self, params: dict, seq: dict, key: jax.Array):
        """Per-step loss ingredients of ONE sequence, each [T] (gate arrays [T, units]).

        Returns ``(terms, posts)``; :meth:`loss` vmaps this over the batch.
        """
        wm, dyn = self.config.wm, self.dynamics
        embeds = self.encode(params, seq)
        posts, priors = self.observe(params, seq, key, embeds)
        feats = jax.vmap(dyn.feat)(posts)
        reward = jnp.tanh(seq["reward"]) if wm.reward_tanh else seq["reward"]
        terms = {
            **self.representation.sequence_terms(params, embeds, feats, seq),
            "reward_logp": normal_log_prob(self.reward_mean(params, feats), reward),
            "kl_rep": self._kl(posts, sg(priors), posts),
            "kl_dyn": self._kl(sg(posts), priors, posts),
            "kl_prior_post": self._kl(priors, posts, posts, masked=False),
            "post_entropy": jax.vmap(dyn.entropy)(posts),
            "prior_entropy": jax.vmap(dyn.entropy)(priors),
        }
        if wm.discount_head:
            terms["discount_logp"] = bernoulli_log_prob(self.discount_logits(params, feats),
                                                        self.discount_target(seq["is_terminal"]))
        if dyn.gated:
            terms["gate_sample"] = jax.vmap(dyn.gates)(posts)[0]
            terms["gate_logit"] = jax.vmap(dyn.gate_logits)(posts)
        return terms, posts

    def _kl(self, lhs, rhs, posts, masked: bool | None = None) -> jax.Array:
        """Per-step KL(lhs || rhs) [T], gate-masked if ``wm.kl_masked`` (or ``masked``)."""
        masked = self.config.wm.kl_masked if masked is None else masked
        return per_step_kl(self.dynamics, lhs, rhs, self._kl_mask(posts) if masked else None)

    def _kl_mask(self, posts) -> jax.Array:
        """The straight-through gate samples [T, D] of the posteriors, one per latent dim (SVSG)."""
        dyn = self.dynamics
        if not dyn.gated:
            raise ValueError(
                f"wm.kl_masked needs a gated model, got model {self.config.agent!r}")
        sample = jax.vmap(dyn.gates)(posts)[0]
        latent_shape = jax.eval_shape(dyn.kl, dyn.initial(), dyn.initial()).shape
        if sample.shape[1:] != latent_shape:
            raise ValueError(
                f"wm.kl_masked needs one gate per latent dimension (svsg); model "
                f"{self.config.agent!r} has gates {sample.shape[1:]} and KL {latent_shape}")
        return sample

    def loss(self, params: dict, batch: dict, key: jax.Array, targets: dict | None = None):
        """World-model loss of a [B, T] batch -> ``(loss, (metrics, posts))``.

        ``posts`` are the posterior states with leading [B, T] dims (the actor-critic's start
        states). ``metrics`` holds every loss term, both KL directions, entropies and gate stats.
        A representation with EMA targets (prototypes) takes the batch of its
        ``training_views`` and its ``targets``.
        """
        wm, rep = self.config.wm, self.representation
        keys = jax.random.split(key, batch["is_first"].shape[0])
        terms, posts = jax.vmap(self.sequence_terms, in_axes=(None, 0, 0))(params, batch, keys)
        kl_rep, kl_dyn = terms["kl_rep"].mean(), terms["kl_dyn"].mean()
        losses = {
            "reward_loss": -wm.reward_scale * terms["reward_logp"].mean(),
            "kl_loss": balanced_kl_loss(kl_rep, kl_dyn, wm.kl_scale, wm.kl_balance, wm.kl_free),
        }
        if wm.discount_head:
            losses["discount_loss"] = -wm.discount_scale * terms["discount_logp"].mean()
        losses = rep.join_losses(losses, params, batch, terms, targets)
        metrics = rep.metrics(losses)
        metrics.update({
            "kl": kl_rep,
            "kl_prior_post": terms["kl_prior_post"].mean(),
            "post_entropy": terms["post_entropy"].mean(),
            "prior_entropy": terms["prior_entropy"].mean(),
        })
        if self.dynamics.gated:
            gate_losses, gate_values = gate_objectives.gate_loss(wm, terms["gate_sample"],
                                                                 terms["gate_logit"])
            losses.update(gate_losses)
            metrics.update(gate_values)
            prob = open_probability(self.dynamics.gate, terms["gate_logit"])
            metrics.update(gates.gate_metrics(terms["gate_sample"], prob))
        loss = sum(losses.values())
        metrics.update(losses, loss=loss)
        return loss, (metrics, posts)
