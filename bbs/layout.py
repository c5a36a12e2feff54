"""Scene layouts: where every entity starts. Sampled from a numpy Generator or given by the user.

A layout given to ``reset(options={"layout": ...})`` is a mapping::

    {"agent": {"position": (x, y), "angle": 0.0},            # angle optional (default 0)
     "objects": [{"position": (x, y), "angle": a, "shape": "square", "colour": "red"}, ...],
     "distractors": [{"position": (x, y), "angle": 0.0}, ...],   # optional (default none)
     "goal_y": 237.5}                                          # optional (default: centred)

``Layout.to_dict()`` returns exactly this form, so a scene can be saved and replayed.
"""

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from bbs.geometry import (
    AGENT_RADIUS,
    DISTRACTOR_RADIUS,
    GOAL_WIDTH,
    OBJECT_COLOURS,
    OBJECT_SHAPES,
    WALL_THICKNESS,
    ArenaGeometry,
    Rect,
)

SHAPE_NAMES = tuple(OBJECT_SHAPES)
COLOUR_NAMES = tuple(OBJECT_COLOURS)
WALL_NAMES = ("left wall", "right wall", "top wall", "bottom wall", "goal's upper wall block",
              "goal's lower wall block")  # in the order of ``ArenaGeometry.walls``


def smallest_arena_size() -> tuple[int, int]:
    """Smallest arena width and length (px) on which the spawn rule below works.

    Every spawn interval must be non-empty (numpy rejects ``uniform(low, high)`` with
    ``high < low``): size >= 2 (wall + radius) for the agent and the distractors, >= 2 walls for
    the objects. And the goal-line clamp, which moves an agent or distractor spawned past
    ``goal_x - r`` to ``goal_x - r`` (``goal_x = width - wall - goal width``), must leave it
    clear of the left wall: ``goal_x - r >= wall + r``. Objects have no such condition: their
    origins always lie inside the outer walls (see ``wall_overlap``).
    """
    radii = (AGENT_RADIUS, DISTRACTOR_RADIUS)
    spawn = max(2 * (WALL_THICKNESS + r) for r in radii)
    clamp = max(2 * WALL_THICKNESS + GOAL_WIDTH + 2 * r for r in radii)
    return int(max(spawn, clamp)), int(spawn)


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


def _disc_hits(rect: Rect, x: float, y: float, radius: float) -> bool:
    """Whether a disc overlaps the rectangle (touching is allowed)."""
    dx = max(rect.x0 - x, 0.0, x - rect.x1)
    dy = max(rect.y0 - y, 0.0, y - rect.y1)
    return dx * dx + dy * dy < radius * radius


def wall_overlap(geometry: ArenaGeometry, kind: str, x: float, y: float) -> str | None:
    """The wall an entity placed at (x, y) would start in, or None.

    What the physics can't undo: pymunk pushes an overlapping shape out through the nearest
    wall face, which for a shape deep in a wall is the arena's outer edge (an agent placed at
    (50, 50) ends at y = -14.9 and stays outside). So, matching the spawn rule:

    * ``"agent"``: its disc (radius 15) must not overlap any wall, at the position it starts
      from, i.e. after the goal-line clamp to ``x <= goal_x - 15``;
    * ``"distractor"``: its spawn disc (radius 12, as the original's spawn rule and clamp use;
      the kite's tip may reach into a wall, as in the original) likewise;
    * ``"object"``: its body origin must lie inside the outer walls (on their faces is fine).
      Its shape may reach into a wall, as sampled objects do (spec defect #12, kept): it is no
      more than 36 px from the origin to the centroid, so pymunk pushes it inwards. An origin
      in a goal block lies within 5 px of the block's face or past the score line, where the
      object scores on the first sub-step.
    """
    walls = geometry.walls
    if kind == "object":
        t = WALL_THICKNESS
        sides = (x < t, x > geometry.width - t, y < t, y > geometry.length - t)
        return next((name for name, hit in zip(WALL_NAMES[:4], sides, strict=True) if hit), None)
    radius = AGENT_RADIUS if kind == "agent" else DISTRACTOR_RADIUS
    x = min(x, geometry.goal_x - radius)
    for name, rect in zip(WALL_NAMES, walls, strict=True):
        if rect.x1 > rect.x0 and rect.y1 > rect.y0 and _disc_hits(rect, x, y, radius):
            return name
    return None


_WALL_RULES = {
    "agent": f"the agent's disc (radius {AGENT_RADIUS:g}) must stay clear of the walls",
    "distractor": f"a distractor's origin must stay {DISTRACTOR_RADIUS:g} px clear of the walls",
    "object": "an object's origin must lie inside the walls",
}


def _check_walls(geometry: ArenaGeometry, kind: str, where: str, placement: Placement) -> None:
    wall = wall_overlap(geometry, kind, placement.x, placement.y)
    if wall is not None:
        raise ValueError(f"layout {where} at ({placement.x:g}, {placement.y:g}) overlaps the "
                         f"arena wall ({wall}): {_WALL_RULES[kind]}")


def parse_layout(spec: Mapping | Layout, geometry: ArenaGeometry) -> Layout:
    """Validate a user layout (see module docstring) against the arena, into a ``Layout``.

    Entities that would start inside a wall are rejected (``wall_overlap``); every layout the
    spawn rule samples passes.
    """
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
        geometry = dataclasses.replace(geometry, goal_y=goal_y)  # the wall blocks move with it
    layout = Layout(
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
    _check_walls(geometry, "agent", "agent", layout.agent)
    for i, placement in enumerate(layout.objects):
        _check_walls(geometry, "object", f"objects[{i}]", placement)
    for i, placement in enumerate(layout.distractors):
        _check_walls(geometry, "distractor", f"distractors[{i}]", placement)
    return layout
