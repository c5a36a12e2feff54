"""The task-family registry: per family, how a task name parses, its preset column, whether it
steps on the device, what it observes and how it acts, and how it is built.

A task name is ``<family>_<rest>`` (``dmc_walker_walk``: family ``dmc``). Adding a family is one
entry here plus its env module; :func:`family_of` is what every other module asks.
"""

from __future__ import annotations

from dataclasses import dataclass

from vsgjax.registry.names import did_you_mean

IMAGE, VECTOR = "image", "vector"  # what a family's observations are
CONTINUOUS, DISCRETE = "continuous", "discrete"  # how its tasks act


class TaskError(ValueError):
    """An unknown or malformed task name; the message lists what is valid."""


@dataclass(frozen=True)
class TaskFamily:
    """One family of tasks.

    ``parse``: ``"module:function"`` of ``(task, rest) -> args`` (raises TaskError);
    ``build``: for a host family, ``"module:function"`` of ``(args, env_cfg, seed, eval) ->
    gymnasium.Env`` (``eval``: an evaluation env); for a device family, of ``(env_cfg) -> task``
    stepped inside JAX.
    ``preset_column``: the column of the presets the family's tasks take (the paper's
    hyperparameter table has one per domain).
    ``options``: the ``env.*`` keys only this family's tasks take (any other task refuses a
    value other than the default); ``check``: ``"module:function"`` of ``(config) -> None``,
    the family's checks of its options against the rest of the config (raises ConfigError),
    run by :func:`vsgjax.config.check_config` before anything is built or written.
    ``windows_cross_episodes``: a device family whose episodes end (terminate) before a
    training sequence is full: the device loop stores several consecutive episodes per env in
    one replay row and samples sequences across their boundaries, ``is_first`` resetting the
    latent state (:mod:`vsgjax.loop.device_program`), so ``train.length`` is not bounded by
    one episode.
    """

    prefix: str
    pattern: str
    description: str
    preset_column: str
    on_device: bool
    observations: str
    actions: str
    parse: str
    build: str
    grayscale_sticky: bool = False  # takes env.grayscale and env.sticky (Atari's options)
    backgrounds: bool = False  # takes env.background and env.background_dir (DMC's option)
    same_tasks_as: str = ""  # the family whose tasks these are, in another simulator
    extra_steps: int = 0  # env steps an episode runs past env.time_limit (BBS's original: 2)
    # its episodes end before env.time_limit as a rule (Atari's game over), so when the first
    # episode ends is not known before training
    ends_early: bool = False
    options: tuple[str, ...] = ()
    check: str = ""
    windows_cross_episodes: bool = False

    def owns(self, task: str) -> bool:
        return task.partition("_")[0] == self.prefix


FAMILIES: dict[str, TaskFamily] = {family.prefix: family for family in (
    TaskFamily("bbs", "bbs_<variant>", "BringBackShapes (the bbs package), the 16 paper variants",
               "bbs", False, IMAGE, CONTINUOUS,
               "vsgjax.envs.bbs_task:parse", "vsgjax.envs.bbs_task:build", extra_steps=2),
    TaskFamily("dmc", "dmc_<domain>_<task>", "DeepMind Control Suite from pixels",
               "dmc", False, IMAGE, CONTINUOUS,
               "vsgjax.envs.dmc:parse", "vsgjax.envs.dmc:build", backgrounds=True),
    TaskFamily("atari", "atari_<game>", "Atari through ale-py, DreamerV2's settings",
               "atari", False, IMAGE, DISCRETE,
               "vsgjax.envs.atari:parse", "vsgjax.envs.atari:build", grayscale_sticky=True,
               ends_early=True),
    TaskFamily("mjx", "mjx_<domain>_<task>",
               "DeepMind Control on MuJoCo MJX, vector observations, stepped on the device",
               "dmc", True, VECTOR, CONTINUOUS,
               "vsgjax.envs.mjx:parse", "vsgjax.envs.mjx:build", same_tasks_as="dmc",
               options=("env.flicker", "env.hide", "env.show_keys", "env.show_steps",
                        "env.noise_dims", "env.noise_scale"),
               check="vsgjax.envs.mjx.options:check"),
    TaskFamily("gymnax", "gymnax_<env>",
               "gymnax's JAX environments (bsuite's MemoryChain), vector observations, stepped "
               "on the device", "gymnax", True, VECTOR, DISCRETE,
               "vsgjax.envs.gymnax_tasks:parse", "vsgjax.envs.gymnax_tasks:build",
               options=("env.memory_length",), check="vsgjax.envs.gymnax_tasks:check",
               windows_cross_episodes=True),
)}

DEFAULT_TASK = "bbs_basic"  # the paper's benchmark: what a config and the command line take
PRESET_COLUMNS = tuple(dict.fromkeys(family.preset_column for family in FAMILIES.values()))


def patterns() -> str:
    return ", ".join(family.pattern for family in FAMILIES.values())


def family_of(task: str) -> TaskFamily:
    """The family of a task name (its prefix); raises TaskError listing the valid patterns.

    Only the prefix is checked here; the family's ``parse`` checks the rest.
    """
    prefix, sep, rest = task.partition("_")
    if not sep or not rest or prefix not in FAMILIES:
        hint = did_you_mean(prefix, FAMILIES, suffix=f"_{rest}") if sep and rest else ""
        raise TaskError(f"unknown task {task!r}{hint}; valid patterns: {patterns()}")
    return FAMILIES[prefix]


def device_families() -> tuple[TaskFamily, ...]:
    """The families whose tasks step inside JAX (the device loop)."""
    return tuple(family for family in FAMILIES.values() if family.on_device)
