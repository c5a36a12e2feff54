"""Arena geometry, entity shapes and colours of BringBackShapes.

Coordinates are world coordinates that double as screen pixels: x points right, y points down.
Only the playable interior grows with the arena scale; walls, goal width, object sizes and the
view box keep their sizes.
"""

from dataclasses import dataclass
from functools import cached_property

WALL_THICKNESS = 125
GOAL_WIDTH = 100
AGENT_RADIUS = 15.0
DISTRACTOR_RADIUS = 12.0  # only used for spawning and for the goal-line clamp
SCORE_MARGIN = 5  # an object scores when its body origin x >= goal_x + SCORE_MARGIN

# Local vertices relative to the body origin (which is also the centre of gravity and the
# rotation centre; for the triangle, square and rectangle it is a corner).
OBJECT_SHAPES: dict[str, tuple[tuple[float, float], ...]] = {
    "triangle": ((0, 0), (50, 0), (25, 25)),
    "square": ((0, 0), (50, 0), (50, 50), (0, 50)),
    "rectangle": ((0, 0), (50, 0), (50, 25), (0, 25)),
    "pentagon": ((5, -17), (-19, 0), (-10, 28), (19, 28), (28, 0)),
    "hexagon": ((17, -14), (-8, -14), (-20, 7), (-8, 29), (17, 29), (30, 8)),
}
DISTRACTOR_VERTICES = ((-30, 0), (0, 15), (10, 0), (0, -15))

# Screen colours (RGB) before the view overlay.
OBJECT_COLOURS: dict[str, tuple[int, int, int]] = {
    "orange": (255, 165, 0),
    "blue": (0, 0, 255),
    "green": (0, 255, 0),
    "red": (255, 0, 0),
    "purple": (160, 32, 240),
}
BACKGROUND_COLOUR = (0, 0, 0)
WALL_COLOUR = (149, 165, 166)  # pymunk's default static-shape colour
GOAL_COLOUR = (0, 130, 65)
AGENT_COLOUR = (70, 130, 180)  # steelblue
AGENT_LINE_COLOUR = (44, 62, 80)
DISTRACTOR_COLOUR = (188, 143, 143)  # rosybrown


@dataclass(frozen=True)
class Rect:
    """Axis-aligned rectangle [x0, x1] x [y0, y1] in world coordinates."""

    x0: float
    y0: float
    x1: float
    y1: float


@dataclass(frozen=True)
class ArenaGeometry:
    """Sizes derived from the arena scale and the goal opening's top edge ``goal_y``."""

    width: int
    length: int
    goal_x: int
    goal_y: float
    goal_height: float

    @property
    def score_x(self) -> float:
        return self.goal_x + SCORE_MARGIN

    @cached_property
    def goal_rect(self) -> Rect:
        goal_bottom = self.goal_y + self.goal_height
        return Rect(self.goal_x, self.goal_y, self.goal_x + GOAL_WIDTH, goal_bottom)

    @cached_property
    def walls(self) -> tuple[Rect, ...]:
        """The 6 static wall boxes: left, right, top, bottom and the two goal blocks."""
        width, length, t = self.width, self.length, WALL_THICKNESS
        inner_right = width - t
        return (
            Rect(0, 0, t, length),
            Rect(inner_right, 0, width, length),
            Rect(0, 0, width, t),
            Rect(0, length - t, width, length),
            Rect(self.goal_x, t, inner_right, self.goal_y),
            Rect(self.goal_x, self.goal_y + self.goal_height, inner_right, length - t),
        )

    @cached_property
    def drawn_goal_rect(self) -> Rect:
        """The goal as the original draws it: ``pygame.Rect`` truncation, right/bottom exclusive."""
        x, y = int(self.goal_x), int(self.goal_y)
        return Rect(x, y, x + GOAL_WIDTH - 1, y + int(self.goal_height) - 1)

    @cached_property
    def drawn_walls(self) -> tuple[Rect, ...]:
        """The walls as the original draws them: vertices rounded, boundary pixels included."""
        return tuple(Rect(round(r.x0), round(r.y0), round(r.x1), round(r.y1)) for r in self.walls)

    @property
    def goal_y_range(self) -> tuple[float, float]:
        """Admissible ``goal_y`` values: the opening must stay between the top and bottom walls."""
        return float(WALL_THICKNESS), self.length - WALL_THICKNESS - self.goal_height


def arena_geometry(scale: float, goal_y: float | None = None) -> ArenaGeometry:
    """Geometry of the original at ``scale``; ``goal_y=None`` centres the opening.

    ``int(700 * 1.4) == 979`` because of float truncation; this is kept (spec defect #8).
    """
    width, length = int(800 * scale), int(700 * scale)
    goal_height = 0.5 * (length - 2 * WALL_THICKNESS)
    if goal_y is None:
        goal_block_height = (length - goal_height - 2 * WALL_THICKNESS) / 2
        goal_y = WALL_THICKNESS + goal_block_height
    goal_x = width - WALL_THICKNESS - GOAL_WIDTH
    return ArenaGeometry(width, length, goal_x, float(goal_y), goal_height)

