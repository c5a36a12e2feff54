"""Scene layouts: where every entity starts. Sampled from a numpy Generator or given by the user.

A layout given to ``reset(options={"layout": ...})`` is a mapping::

    {"agent": {"position": (x, y), "angle": 0.0},            # angle optional (default 0)
     "objects": [{"position": (x, y), "angle": a, "shape": "square", "colour": "red"}, ...],
     "distractors": [{"position": (x, y), "angle": 0.0}, ...],   # optional (default none)
     "goal_y": 237.5}                                          # optional (default: centred)

``Layout.to_dict()`` returns exactly this form, so a scene can be saved and replayed.
"""

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from bbs.geometry import (
    AGENT_RADIUS,
    DISTRACTOR_RADIUS,
    OBJECT_COLOURS,
    OBJECT_SHAPES,
    WALL_THICKNESS,
    ArenaGeometry,
)

SHAPE_NAMES = tuple(OBJECT_SHAPES)
COLOUR_NAMES = tuple(OBJECT_COLOURS)


@dataclass(frozen=True)
class Placement:
    x: float
    y: float
    angle: float = 0.0


@dataclass(frozen=True)
class ObjectPlacement(Placement):
    shape: str = "square"
    colour: str = "red"


@dataclass(frozen=True)
class Layout:
    agent: Placement
    objects: tuple[ObjectPlacement, ...]
    distractors: tuple[Placement, ...]
    goal_y: float | None = None

    def to_dict(self) -> dict:
        def place(p: Placement) -> dict:
            return {"position": (p.x, p.y), "angle": p.angle}

        return {
            "agent": place(self.agent),
            "objects": [place(o) | {"shape": o.shape, "colour": o.colour} for o in self.objects],
            "distractors": [place(d) for d in self.distractors],
            "goal_y": self.goal_y,
        }


def _centred_uniform(rng: np.random.Generator, size: int, margin: float) -> float:
    """``U(-g/2, g/2) + size // 2`` with ``g = size - 2 * margin``, the original's spawn rule."""
    half_gap = (size - 2 * margin) / 2
    return float(rng.uniform(-half_gap, half_gap)) + size // 2


def sample_layout(
    rng: np.random.Generator,
    geometry: ArenaGeometry,
    num_objects: int,
    num_distractors: int,
    goal_y: float | None,
) -> Layout:
    """Spawn rule of spec 3.2, drawing in the original's order.

    Agent (x, y), then each distractor (x, y), then each object (x, y, angle, shape, colour).
    Objects may overlap walls and each other (kept, spec defect #12); pymunk separates them.
    """
    margin_agent = WALL_THICKNESS + AGENT_RADIUS
    agent = Placement(
        _centred_uniform(rng, geometry.width, margin_agent),
        _centred_uniform(rng, geometry.length, margin_agent),
    )
    margin_distractor = WALL_THICKNESS + DISTRACTOR_RADIUS
    distractors = tuple(
        Placement(
            _centred_uniform(rng, geometry.width, margin_distractor),
            _centred_uniform(rng, geometry.length, margin_distractor),
        )
        for _ in range(num_distractors)
    )
    spawn_width = 0.7 * (geometry.width - 2 * WALL_THICKNESS)
    objects = []
    for _ in range(num_objects):
        x = WALL_THICKNESS + float(rng.uniform(0.0, spawn_width))
        y = float(rng.uniform(WALL_THICKNESS, geometry.length - WALL_THICKNESS))
        angle = float(rng.random()) * 2 * np.pi
        shape = SHAPE_NAMES[int(rng.integers(len(SHAPE_NAMES)))]
        colour = COLOUR_NAMES[int(rng.integers(len(COLOUR_NAMES)))]
        objects.append(ObjectPlacement(x, y, angle, shape, colour))
    return Layout(agent, tuple(objects), distractors, goal_y)


def _placement_fields(entry: Mapping, where: str, geometry: ArenaGeometry) -> dict:
    if not isinstance(entry, Mapping) or "position" not in entry:
        raise ValueError(f"layout {where} must be a mapping with 'position': (x, y); got {entry!r}")
    position = entry["position"]
    if len(position) != 2 or not all(np.isfinite(float(v)) for v in position):
        raise ValueError(f"layout {where} position must be two finite numbers; got {position!r}")
    x, y = (float(v) for v in position)
    if not (0 <= x <= geometry.width and 0 <= y <= geometry.length):
        raise ValueError(f"layout {where} position {position!r} lies outside the "
                         f"{geometry.width}x{geometry.length} arena")
    angle = float(entry.get("angle", 0.0))
    if not np.isfinite(angle):
        raise ValueError(f"layout {where} angle must be finite; got {angle!r}")
    return {"x": x, "y": y, "angle": angle}


def _object_placement(entry: Mapping, index: int, geometry: ArenaGeometry) -> ObjectPlacement:
    where = f"objects[{index}]"
    fields = _placement_fields(entry, where, geometry)
    shape, colour = entry.get("shape"), entry.get("colour")
    if shape not in OBJECT_SHAPES:
        raise ValueError(f"layout {where} shape {shape!r} is not one of {SHAPE_NAMES}")
    if colour not in OBJECT_COLOURS:
        raise ValueError(f"layout {where} colour {colour!r} is not one of {COLOUR_NAMES}")
    return ObjectPlacement(**fields, shape=shape, colour=colour)


def parse_layout(spec: Mapping | Layout, geometry: ArenaGeometry) -> Layout:
    """Validate a user layout (see module docstring) against the arena, into a ``Layout``."""
    if isinstance(spec, Layout):
        spec = spec.to_dict()
    if not isinstance(spec, Mapping) or "agent" not in spec:
        raise ValueError(f"layout must be a mapping with at least an 'agent' entry; got {spec!r}")
    unknown = set(spec) - {"agent", "objects", "distractors", "goal_y"}
    if unknown:
        raise ValueError(f"layout has unknown keys {sorted(unknown)}")
    goal_y = spec.get("goal_y")
    if goal_y is not None:
        low, high = geometry.goal_y_range
        if not low <= float(goal_y) <= high:
            raise ValueError(f"layout goal_y={goal_y!r} must lie in [{low}, {high}]")
        goal_y = float(goal_y)
    return Layout(
        agent=Placement(**_placement_fields(spec["agent"], "agent", geometry)),
        objects=tuple(
            _object_placement(o, i, geometry) for i, o in enumerate(spec.get("objects", ()))
        ),
        distractors=tuple(
            Placement(**_placement_fields(d, f"distractors[{i}]", geometry))
            for i, d in enumerate(spec.get("distractors", ()))
        ),
        goal_y=goal_y,
    )
