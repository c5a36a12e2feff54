"""The agent registry: every ``--model`` name, the agent that implements it, its display name,
its presets and what it can train on.

An entry's ``implementation`` is the agent class (``"module:Class"``, built as
``Class(config, obs_shape, action_dim, discrete)``; see :mod:`vsgjax.agents.interface`),
``settings`` the module of its family's config sections (their dataclasses, ranges and checks;
``sections`` names the ones the agent reads) and ``presets`` the module of its family's preset
tables (``COLUMN`` and ``SIZE`` layers, pure data, for the preset columns it supports). The
entry's own layers (``model``, ``by_column``, ``by_size``) hold what differs between agents of
one family. :func:`vsgjax.config.make_config` applies, in order: the family's
column layer, the entry's ``model`` layer, its ``by_column`` layer, the family's size layer, the
entry's ``by_size`` layer, then the command line's overrides.

Adding an agent: its package under ``vsgjax/agents/`` (its agent class, settings and presets
modules), and one entry here (docs/architecture.md shows DrQ-v2 as the example); nothing under
``vsgjax/config/`` changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from vsgjax.registry.names import did_you_mean
from vsgjax.registry.tasks import CONTINUOUS, DISCRETE, IMAGE, VECTOR

# Config sections every agent reads; an agent names the others it reads in ``sections``.
SHARED_SECTIONS = ("env", "train")
# Keys outside the agent's sections that every agent takes: the matmul dtype (a top-level field
# of the config that the command line sets as ``model.precision``).
SHARED_KEYS = ("model.precision",)


@dataclass(frozen=True)
class AgentEntry:
    """One ``--model`` name.

    ``options``: family-specific facts as ``(key, value)`` pairs (the Dreamer family's
    ``dynamics``: the name of its latent dynamics class in ``vsgjax/agents/dreamer/dynamics/``;
    its ``representation``: ``reconstruction``, the default, or ``prototypes``, DreamerPro's).
    """

    name: str
    display: str
    implementation: str
    settings: str
    presets: str
    sections: tuple[str, ...]
    gated: bool = False
    actions: tuple[str, ...] = (CONTINUOUS, DISCRETE)
    observations: tuple[str, ...] = (IMAGE, VECTOR)
    model: dict = field(default_factory=dict, hash=False)
    by_column: dict = field(default_factory=dict, hash=False)
    by_size: dict = field(default_factory=dict, hash=False)
    options: tuple[tuple[str, str], ...] = ()

    def option(self, key: str, default: str | None = None) -> str:
        value = dict(self.options).get(key, default)
        if value is None:
            raise KeyError(f"model {self.name!r} has no option {key!r}")
        return value

    def takes(self, key: str) -> bool:
        """Whether a dotted config key is one this agent reads."""
        section = key.partition(".")[0]
        return section in SHARED_SECTIONS or section in self.sections or key in SHARED_KEYS


_DREAMER = "vsgjax.agents.dreamer.agent:DreamerAgent"
_DREAMER_SETTINGS = "vsgjax.agents.dreamer.settings"
_DREAMER_PRESETS = "vsgjax.agents.dreamer.presets"
_DREAMER_MODULES = (_DREAMER, _DREAMER_SETTINGS, _DREAMER_PRESETS)
_DREAMER_SECTIONS = ("model", "wm", "ac", "optim")
# DreamerPro (fdeng18/dreamer-pro, configs.yaml: `defaults` then `dmc`): no decoder, prototypes;
# its DMC world model and actor-critic sizes, in the layer after the family's column.
_PRO_SECTIONS = (*_DREAMER_SECTIONS, "proto")
_PRO_DMC = {"model.deter": 200, "model.hidden": 200, "wm.cnn_depth": 48, "wm.reward_layers": 4,
            "wm.weight_decay": 1e-6, "wm.reward_scale": 1.0, "ac.critic_layers": 4,
            "ac.weight_decay": 1e-6, "ac.actor_dist": "tanh_normal", "train.prefill": 5000,
            "train.length": 51, "train.eval_episodes": 10, "proto.sinkhorn_eps": 0.0125}
_PRO_OPTIONS = (("dynamics", "RSSM"), ("representation", "prototypes"))

AGENTS: dict[str, AgentEntry] = {entry.name: entry for entry in (
    AgentEntry(
        "dreamerv1", "DreamerV1", *_DREAMER_MODULES, _DREAMER_SECTIONS,
        model={"model.stoch": 30, "model.classes": 0, "model.cell_norm": True},
        by_column={"bbs": {"wm.kl_free": 1.0, "model.stoch": 32},  # bringbackshapes_gaussian
                   "dmc": {"model.deter": 200, "model.hidden": 200}},
        by_size={"cpu": {"model.stoch": 16}, "debug": {"model.stoch": 8}},
        options=(("dynamics", "RSSM"),)),
    AgentEntry(
        "dreamerv2", "DreamerV2", *_DREAMER_MODULES, _DREAMER_SECTIONS,
        model={"model.stoch": 32, "model.classes": 32, "model.cell_norm": True},
        by_size={"small": {"model.stoch": 16, "model.classes": 16},
                 "cpu": {"model.stoch": 8, "model.classes": 8},
                 "debug": {"model.stoch": 4, "model.classes": 4}},
        options=(("dynamics", "RSSM"),)),
    AgentEntry(
        "vsg", "VSG", *_DREAMER_MODULES, _DREAMER_SECTIONS, gated=True,
        model={"model.stoch": 32, "model.classes": 32, "model.cell_norm": False},
        by_size={"small": {"model.stoch": 16, "model.classes": 16},
                 "cpu": {"model.stoch": 8, "model.classes": 8},
                 "debug": {"model.stoch": 4, "model.classes": 4}},
        options=(("dynamics", "RSSM"),)),
    AgentEntry(
        "svsg", "SVSG", *_DREAMER_MODULES, _DREAMER_SECTIONS, gated=True,
        model={"model.deter": 0, "model.stoch": 1024, "model.classes": 0,
               "model.cell_norm": False, "wm.kl_masked": True},
        by_column={"bbs": {"wm.kl_free": 1.0}},
        by_size={"small": {"model.deter": 0, "model.stoch": 256},
                 "cpu": {"model.deter": 0, "model.stoch": 128},
                 "debug": {"model.deter": 0, "model.stoch": 32}},
        options=(("dynamics", "SVSG"),)),
    AgentEntry(
        "ssm", "SSM", *_DREAMER_MODULES, _DREAMER_SECTIONS,
        model={"model.deter": 0, "model.stoch": 30, "model.classes": 0,
               "model.cell_norm": False},
        by_size={"small": {"model.deter": 0}, "cpu": {"model.deter": 0, "model.stoch": 16},
                 "debug": {"model.deter": 0, "model.stoch": 8}},
        options=(("dynamics", "SSM"),)),
    AgentEntry(
        "dreamerpro", "DreamerPro", *_DREAMER_MODULES, _PRO_SECTIONS,
        observations=(IMAGE,),
        model={"model.stoch": 32, "model.classes": 0, "model.cell_norm": True},
        by_column={"dmc": _PRO_DMC}, by_size={"debug": {"model.stoch": 8}},
        options=_PRO_OPTIONS),
    AgentEntry(
        # the VSG paper's VSGPro: DreamerPro with VSG's sparse-gated cell and sparsity loss
        "vsgpro", "VSGPro", *_DREAMER_MODULES, _PRO_SECTIONS, gated=True,
        observations=(IMAGE,),
        model={"model.stoch": 32, "model.classes": 0, "model.cell_norm": False},
        by_column={"dmc": _PRO_DMC}, by_size={"debug": {"model.stoch": 8}},
        options=_PRO_OPTIONS),
    AgentEntry(
        "drqv2", "DrQ-v2", "vsgjax.agents.drqv2.agent:DrQV2Agent",
        "vsgjax.agents.drqv2.settings", "vsgjax.agents.drqv2.presets", ("drq",),
        actions=(CONTINUOUS,)),
)}

MODELS = tuple(AGENTS)
DEFAULT_MODEL = "vsg"  # the paper's model: what a config and the command line take by default


def agent_entry(name: str) -> AgentEntry:
    """The entry of a ``--model`` name; ValueError listing the valid names."""
    if name not in AGENTS:
        raise ValueError(f"unknown model {name!r}{did_you_mean(name, MODELS)}; valid: "
                         f"{', '.join(MODELS)}")
    return AGENTS[name]


def dreamer_models() -> tuple[str, ...]:
    """The models of the Dreamer family (a world model with latent dynamics)."""
    return tuple(name for name, entry in AGENTS.items() if entry.implementation == _DREAMER)


def prototype_models() -> tuple[str, ...]:
    """The Dreamer models that learn from prototypes instead of a decoder (DreamerPro's)."""
    return tuple(name for name, entry in AGENTS.items()
                 if entry.option("representation", "reconstruction") == "prototypes")


def gated_models() -> tuple[str, ...]:
    """The models whose latent states carry update gates (VSG's and SVSG's)."""
    return tuple(name for name, entry in AGENTS.items() if entry.gated)
