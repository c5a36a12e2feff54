"""BringBackShapes: a fast, seedable gymnasium reimplementation of the paper's benchmark.

Variants (the paper's 16): arena size Basic/Small/Medium/Large (scale 1.0/1.2/1.4/1.6) times
0/1/2/4 distractors. Task names ``bbs_<size>`` (no distractors) or ``bbs_<size>_d<k>``, e.g.
``bbs_basic``, ``bbs_basic_d2``, ``bbs_medium_d4``; gymnasium ids
``BringBackShapes-<Size>-D<k>-v0``, e.g. ``BringBackShapes-Medium-D4-v0``.

    env = bbs.make("bbs_medium_d4")                          # or
    env = gymnasium.make("BringBackShapes-Medium-D4-v0")     # or
    env = gymnasium.make("BringBackShapes-v0", arena_scale=1.4, num_distractors=4)
"""

import gymnasium

from bbs.env import BringBackShapesEnv
from bbs.layout import Layout

ARENA_SCALES = {"basic": 1.0, "small": 1.2, "medium": 1.4, "large": 1.6}
DISTRACTOR_COUNTS = (0, 1, 2, 4)
ENTRY_POINT = "bbs.env:BringBackShapesEnv"


def _task_name(size: str, distractors: int) -> str:
    return f"bbs_{size}" if distractors == 0 else f"bbs_{size}_d{distractors}"


def _gym_id(size: str, distractors: int) -> str:
    return f"BringBackShapes-{size.capitalize()}-D{distractors}-v0"


VARIANTS: dict[str, dict] = {
    _task_name(size, d): {"arena_scale": scale, "num_distractors": d}
    for size, scale in ARENA_SCALES.items()
    for d in DISTRACTOR_COUNTS
}
VARIANT_IDS: dict[str, str] = {
    _task_name(size, d): _gym_id(size, d) for size in ARENA_SCALES for d in DISTRACTOR_COUNTS
}


def variant_kwargs(name: str) -> dict:
    """Constructor keyword arguments of a paper variant, e.g. ``"bbs_medium_d4"``."""
    if name not in VARIANTS:
        valid = ", ".join(VARIANTS)
        raise ValueError(f"unknown BringBackShapes variant {name!r}; valid names: {valid}")
    return dict(VARIANTS[name])


def make(name: str, **overrides) -> BringBackShapesEnv:
    """Build a variant by task name with other options (e.g. ``time_limit``, ``render_mode``).

    The variant fixes ``arena_scale`` and ``num_distractors``: giving either another value is a
    ValueError (``gymnasium.make("BringBackShapes-v0", ...)`` takes any).
    """
    variant = variant_kwargs(name)
    for key, value in overrides.items():
        if key in variant and value != variant[key]:
            raise ValueError(f"bbs.make({name!r}, {key}={value!r}): variant {name} has "
                             f"{key}={variant[key]!r}; valid: that value, another variant, or "
                             f"gymnasium.make('BringBackShapes-v0', {key}={value!r}, ...)")
    return BringBackShapesEnv(**(variant | overrides))


def _register() -> None:
    if "BringBackShapes-v0" not in gymnasium.registry:
        gymnasium.register("BringBackShapes-v0", entry_point=ENTRY_POINT)
    for name, gym_id in VARIANT_IDS.items():
        if gym_id not in gymnasium.registry:
            gymnasium.register(gym_id, entry_point=ENTRY_POINT, kwargs=VARIANTS[name])


_register()

__all__ = ["VARIANTS", "VARIANT_IDS", "BringBackShapesEnv", "Layout", "make", "variant_kwargs"]
