"""BringBackShapes tasks (``bbs_<variant>``), built by the ``bbs`` package.

The 16 paper variants are ``bbs_<size>`` and ``bbs_<size>_d<k>`` for size in basic / small /
medium / large (arena scale 1.0 / 1.2 / 1.4 / 1.6) and k in 1 / 2 / 4 distractors; their
constructor arguments come from ``bbs.variant_kwargs``. Action repeat and the time limit are the
env's own (the time limit counts physics sub-steps: 3000 with repeat 4 gives 751 agent steps),
so they are passed through rather than wrapped a second time. At the end of an episode the env's
``info["discovery"]`` holds the paper's discovery metrics.
"""

from __future__ import annotations

import gymnasium

from vsgjax.envs.spec import one_of


def variant_names() -> list[str]:
    """Variant names without the ``bbs_`` prefix, e.g. ``basic``, ``medium_d4``."""
    import bbs

    return [name.removeprefix("bbs_") for name in bbs.VARIANTS]


def make_bbs(variant: str, *, action_repeat: int, time_limit: int, size: int) -> gymnasium.Env:
    import bbs

    return bbs.make(f"bbs_{variant}", action_repeat=action_repeat, time_limit=time_limit,
                    obs_size=size)


def parse(task: str, variant: str) -> tuple[str]:
    """``bbs_<variant>`` -> ``(variant,)``; TaskError listing the variants otherwise."""
    return (one_of(task, variant, variant_names(), "BringBackShapes variant"),)


def build(args: tuple[str], cfg, seed: int, eval: bool) -> gymnasium.Env:
    return make_bbs(args[0], action_repeat=cfg.action_repeat, time_limit=cfg.time_limit,
                    size=cfg.image_size)
