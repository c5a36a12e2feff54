"""Drawing with OpenCV: the agent's view (the observation) and the full arena (``rgb_array``).

Scene order follows the original (spec 3.7): background, goal rectangle, dynamic shapes
(objects, distractors, agent with its orientation line), then the static walls on top. The
original's debug collision-point segments are not drawn (spec defect #13, a deviation).

The observation is drawn on a ``canvas_size`` square canvas covering the view box and, when
``canvas_size`` differs from the observation size, resized with ``cv2.INTER_AREA``. Inside the
view box every colour is the screen colour under the original's grey overlay (``view_colour``).

Fill rules. The observation samples pixel centres: a pixel takes a shape's colour when its
centre lies inside the shape. Drawn areas are then unbiased, and the hard edges fall where the
original's bilinear 250 -> 64 resize of its aliased frame puts them (the resize samples that
frame at the same points). ``cv2.fillConvexPoly`` on its own also fills every pixel its outline
walk touches, about half a pixel around each edge (+15..39% area at 64x64). So every polygon
edge is first moved inwards along its minor axis (the axis in which that walk rounds) by
``EDGE_SHRINK`` pixels: 0.5 in principle, 0.52 as measured to cancel what the walk's rounding
near the vertices still adds. Mean drawn areas are then within 1% of the true areas, and about
2-4 pixels per shape differ from exact centre sampling. The agent disc does not rotate: it is an
exact centre-sampled mask, cached per 1/32-px phase. Walls and the goal are exact pixel
ranges. The full arena (``draw_arena``, 1 px per world unit) keeps cv2's inclusive rule, which
is pygame's (boundary pixels included).
"""

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from bbs.geometry import (
    AGENT_COLOUR,
    AGENT_LINE_COLOUR,
    AGENT_RADIUS,
    BACKGROUND_COLOUR,
    DISTRACTOR_COLOUR,
    DISTRACTOR_VERTICES,
    GOAL_COLOUR,
    OBJECT_COLOURS,
    OBJECT_SHAPES,
    WALL_COLOUR,
    ArenaGeometry,
    Rect,
)
from bbs.physics import Pose, Scene

OVERLAY_GREY, OVERLAY_ALPHA = 128, 100
SUBPIXEL_BITS = 8  # cv2 fixed-point fraction bits for vertex coordinates
_SUBPIXEL = 1 << SUBPIXEL_BITS
# Inward move of every polygon edge, in canvas pixels along the edge's minor axis, that turns
# cv2's outline-inclusive fill into pixel-centre sampling (0.5 in principle; 0.52 measured:
# mean drawn area of each shape within 1% of its true area, experiments/bench/bench_bbs.py).
EDGE_SHRINK = 0.52
DISC_PHASES = 32  # the agent disc's centre is placed to 1/32 px (masks cached per phase)
# Farthest any object vertex lies from its body origin (the square's far corner).
_OBJECT_REACH = max(math.hypot(x, y) for v in OBJECT_SHAPES.values() for x, y in v)
_DISTRACTOR_REACH = max(math.hypot(x, y) for x, y in DISTRACTOR_VERTICES)


def view_colour(rgb: tuple[int, int, int]) -> tuple[int, int, int]:
    """Colour under the view box's grey overlay, as measured on the original.

    ``v' = v + (((128 - v) * 100 + 128) >> 8)`` with an arithmetic (flooring) shift.
    """
    return tuple(v + (((OVERLAY_GREY - v) * OVERLAY_ALPHA + 128) >> 8) for v in rgb)


@dataclass(frozen=True)
class Palette:
    background: tuple[int, int, int]
    wall: tuple[int, int, int]
    goal: tuple[int, int, int]
    agent: tuple[int, int, int]
    agent_line: tuple[int, int, int]
    distractor: tuple[int, int, int]
    objects: dict[str, tuple[int, int, int]]

    def under_overlay(self) -> "Palette":
        return Palette(
            *(view_colour(c) for c in (self.background, self.wall, self.goal, self.agent,
                                       self.agent_line, self.distractor)),
            objects={name: view_colour(c) for name, c in self.objects.items()},
        )


SCREEN_PALETTE = Palette(
    BACKGROUND_COLOUR, WALL_COLOUR, GOAL_COLOUR, AGENT_COLOUR, AGENT_LINE_COLOUR,
    DISTRACTOR_COLOUR, dict(OBJECT_COLOURS),
)
VIEW_PALETTE = SCREEN_PALETTE.under_overlay()


@dataclass(frozen=True)
class ViewBox:
    """The agent's view: a square of ``size`` world px with integer top-left corner."""

    x0: int
    y0: int
    size: int

    def contains(self, x0: float, y0: float, x1: float, y1: float) -> bool:
        """Whether the rectangle [x0, x1] x [y0, y1] lies completely inside the box."""
        return (x0 >= self.x0 and x1 <= self.x0 + self.size
                and y0 >= self.y0 and y1 <= self.y0 + self.size)


def view_box(agent: Pose, half_size: int, geometry: ArenaGeometry) -> ViewBox:
    """``[clip(x - h, 0, w - 2h), clip(y - h, 0, l - 2h)]`` truncated to int, as pygame.Rect."""
    size = 2 * half_size
    x0 = min(max(agent.x - half_size, 0.0), geometry.width - size)
    y0 = min(max(agent.y - half_size, 0.0), geometry.length - size)
    return ViewBox(int(x0), int(y0), size)


@dataclass(frozen=True)
class Outline:
    """A convex polygon's local vertices with what shrinking its edges needs.

    ``normals[i]`` is the inward unit normal of edge i (vertex i to i + 1). Moving edge i
    inwards by ``d[i]`` moves vertex i by ``d[i - 1] * duals[i][0] + d[i] * duals[i][1]``.
    """

    vertices: tuple[tuple[float, float], ...]
    normals: tuple[tuple[float, float], ...]
    duals: tuple[tuple[tuple[float, float], tuple[float, float]], ...]


def outline(vertices) -> Outline:
    """The ``Outline`` of a convex polygon given by its local vertices (either winding)."""
    n = len(vertices)
    cx, cy = sum(x for x, _ in vertices) / n, sum(y for _, y in vertices) / n
    normals = []
    for i, (x0, y0) in enumerate(vertices):
        x1, y1 = vertices[(i + 1) % n]
        length = math.hypot(x1 - x0, y1 - y0)
        nx, ny = (y0 - y1) / length, (x1 - x0) / length
        if nx * (cx - x0) + ny * (cy - y0) < 0:
            nx, ny = -nx, -ny
        normals.append((nx, ny))
    duals = []
    for i in range(n):
        (ax, ay), (bx, by) = normals[i - 1], normals[i]
        det = ax * by - ay * bx
        duals.append(((by / det, -bx / det), (-ay / det, ax / det)))
    return Outline(tuple(map(tuple, vertices)), tuple(normals), tuple(duals))


OBJECT_OUTLINES = {name: outline(v) for name, v in OBJECT_SHAPES.items()}
DISTRACTOR_OUTLINE = outline(DISTRACTOR_VERTICES)


def placed_vertices(local: tuple[tuple[float, float], ...],
                    pose: Pose) -> tuple[list[float], list[float]]:
    """World x and y of local polygon vertices placed at ``pose`` (rotation about the origin)."""
    c, s = math.cos(pose.angle), math.sin(pose.angle)
    x, y = pose.x, pose.y
    return [x + c * lx - s * ly for lx, ly in local], [y + s * lx + c * ly for lx, ly in local]


@functools.lru_cache(maxsize=1024)
def _disc_mask(radius: float, phase_x: int, phase_y: int) -> tuple[np.ndarray, int]:
    """RGB mask of the pixels whose centres lie in a disc of ``radius`` px, and its half size n.

    The disc's centre is ``phase / DISC_PHASES`` px right of and below pixel (n, n) of the
    mask. The disc does not rotate, so its mask depends only on this sub-pixel phase.
    """
    n = math.ceil(radius) + 1
    offsets = np.arange(-n, n + 1, dtype=np.float64)
    dx, dy = offsets - phase_x / DISC_PHASES, offsets - phase_y / DISC_PHASES
    inside = dy[:, None] ** 2 + dx[None, :] ** 2 <= radius * radius
    return np.repeat(inside[:, :, None], 3, axis=2), n


class _Canvas:
    """An RGB image of the world drawn in one palette, at ``scale`` image px per world px.

    ``draw`` shows the world from ``origin`` on. Pixel centres sit at integer world coordinates
    at scale 1, like pygame's; at other scales the mapping is that of a resize:
    u = (x - origin + 0.5) * scale - 0.5. Shapes are filled without anti-aliasing (hard edges,
    like the original's bilinear 250 -> 64 downscale of an aliased drawing); vertices keep
    ``SUBPIXEL_BITS`` of sub-pixel precision.

    ``centre_sampled`` selects the fill rule of the polygons and the agent disc (see the module
    docstring): pixel centres inside the shape (the observation), or cv2's inclusive rule, which
    is pygame's (the full arena, and the 250x250 frame of the original's pipeline). Walls and
    the goal are pygame's inclusive rectangles, i.e. the squares of the pixels they cover at
    scale 1, filled by pixel centre in both modes (at scale 1: pygame's pixels exactly).
    """

    def __init__(self, image: np.ndarray, scale: float, palette: Palette,
                 centre_sampled: bool = True):
        self.image, self.scale, self.palette = image, scale, palette
        self.centre_sampled = centre_sampled
        self.shrink = EDGE_SHRINK * _SUBPIXEL if centre_sampled else 0.0
        self.background = np.empty_like(image)
        self.background[...] = palette.background
        self.agent_colour = np.array(palette.agent, dtype=image.dtype)
        # The agent's orientation line is 1 world px wide. Below scale 1 it is thinner than an
        # image pixel, so it is drawn one pixel wide in the colour it averages to.
        share = min(1.0, scale)
        pairs = zip(palette.agent, palette.agent_line, strict=True)
        self.agent_line = tuple(round(c + share * (lc - c)) for c, lc in pairs)
        self.line_thickness = max(1, round(scale))
        self.agent_radius = round(AGENT_RADIUS * scale * _SUBPIXEL)
        self._fixed_scale = scale * _SUBPIXEL

    def _set_origin(self, x0: float, y0: float) -> None:
        height, width = self.image.shape[:2]
        margin = 1.0 / self.scale  # cull against the covered world rectangle plus one pixel
        self.bounds = (x0 - margin, y0 - margin,
                       x0 + width / self.scale + margin, y0 + height / self.scale + margin)
        self._origin = (x0, y0)
        self._offset_x = (0.5 - x0) * self._fixed_scale - 0.5 * _SUBPIXEL
        self._offset_y = (0.5 - y0) * self._fixed_scale - 0.5 * _SUBPIXEL

    def _fixed(self, x: float, y: float) -> tuple[int, int]:
        return (round(x * self._fixed_scale + self._offset_x),
                round(y * self._fixed_scale + self._offset_y))

    def overlaps(self, x0: float, y0: float, x1: float, y1: float) -> bool:
        bx0, by0, bx1, by1 = self.bounds
        return x0 <= bx1 and x1 >= bx0 and y0 <= by1 and y1 >= by0

    def polygon(self, shape: Outline, angle: float, xs: list[float], ys: list[float],
                colour) -> None:
        """Fill the placed polygon ``xs, ys``: ``shape`` rotated by ``angle``."""
        scale, ox, oy = self._fixed_scale, self._offset_x, self._offset_y
        if not self.shrink:
            fixed = [(round(x * scale + ox), round(y * scale + oy))
                     for x, y in zip(xs, ys, strict=True)]
        else:
            # Edge i moves inwards by k * max(|n_x|, |n_y|) (its rotated normal n), i.e. by k
            # along its minor axis; each vertex follows its two edges.
            c, s, k = math.cos(angle), math.sin(angle), self.shrink
            d = [k * max(abs(c * nx - s * ny), abs(s * nx + c * ny)) for nx, ny in shape.normals]
            fixed = []
            for i, ((ax, ay), (bx, by)) in enumerate(shape.duals):
                qx, qy = d[i - 1] * ax + d[i] * bx, d[i - 1] * ay + d[i] * by
                fixed.append((round(xs[i] * scale + ox + c * qx - s * qy),
                              round(ys[i] * scale + oy + s * qx + c * qy)))
        cv2.fillConvexPoly(self.image, np.array(fixed, dtype=np.int32), colour, cv2.LINE_8,
                           SUBPIXEL_BITS)

    def rectangle(self, rect: Rect, colour) -> None:
        """Fill pygame's inclusive rectangle: world [x0 - 0.5, x1 + 0.5] x [y0 - 0.5, y1 + 0.5].

        The image pixels whose centres lie in it (half-open intervals).
        """
        if not self.overlaps(rect.x0, rect.y0, rect.x1, rect.y1):
            return
        (x0, y0), scale = self._origin, self.scale
        # u = (x - x0 + 0.5) * scale - 0.5 at x = rect.x0 - 0.5 and at x = rect.x1 + 0.5.
        left = math.ceil((rect.x0 - x0) * scale - 0.5)
        right = math.ceil((rect.x1 + 1 - x0) * scale - 0.5) - 1
        top = math.ceil((rect.y0 - y0) * scale - 0.5)
        bottom = math.ceil((rect.y1 + 1 - y0) * scale - 0.5) - 1
        if left <= right and top <= bottom:
            cv2.rectangle(self.image, (left, top), (right, bottom), colour, -1)

    def _disc(self, x: float, y: float) -> None:
        """Fill the pixels whose centres lie in the agent disc centred at world (x, y)."""
        (x0, y0), scale = self._origin, self.scale
        column, phase_x = divmod(round(((x - x0 + 0.5) * scale - 0.5) * DISC_PHASES), DISC_PHASES)
        row, phase_y = divmod(round(((y - y0 + 0.5) * scale - 0.5) * DISC_PHASES), DISC_PHASES)
        mask, n = _disc_mask(AGENT_RADIUS * scale, phase_x, phase_y)
        height, width = self.image.shape[:2]
        top, left = row - n, column - n
        r0, c0 = max(top, 0), max(left, 0)
        r1, c1 = min(top + 2 * n + 1, height), min(left + 2 * n + 1, width)
        if r0 < r1 and c0 < c1:
            np.copyto(self.image[r0:r1, c0:c1], self.agent_colour,
                      where=mask[r0 - top:r1 - top, c0 - left:c1 - left])

    def agent(self, pose: Pose) -> None:
        """A disc and a line from its centre to the rim at the body angle."""
        x, y, r = pose.x, pose.y, AGENT_RADIUS
        if not self.overlaps(x - r, y - r, x + r, y + r):
            return
        centre = self._fixed(x, y)
        tip = self._fixed(x + r * math.cos(pose.angle), y + r * math.sin(pose.angle))
        if self.centre_sampled:
            self._disc(x, y)
        else:
            cv2.circle(self.image, centre, self.agent_radius, self.palette.agent, -1, cv2.LINE_8,
                       SUBPIXEL_BITS)
        cv2.line(self.image, centre, tip, self.agent_line, self.line_thickness, cv2.LINE_8,
                 SUBPIXEL_BITS)

    def draw(self, scene: Scene, geometry: ArenaGeometry, origin: tuple[float, float],
             box: ViewBox) -> list[int]:
        """Draw ``scene``; returns the layout indices of the objects completely inside ``box``."""
        self._set_origin(*origin)
        palette = self.palette
        np.copyto(self.image, self.background)
        self.rectangle(geometry.drawn_goal_rect, palette.goal)
        fully_visible = []
        reach = _OBJECT_REACH
        for pose, shape, colour, index in zip(scene.objects, scene.object_shapes,
                                              scene.object_colours, scene.object_ids, strict=True):
            if not self.overlaps(pose.x - reach, pose.y - reach, pose.x + reach, pose.y + reach):
                continue
            xs, ys = placed_vertices(OBJECT_SHAPES[shape], pose)
            x0, y0, x1, y1 = min(xs), min(ys), max(xs), max(ys)
            if self.overlaps(x0, y0, x1, y1):
                self.polygon(OBJECT_OUTLINES[shape], pose.angle, xs, ys, palette.objects[colour])
            if box.contains(x0, y0, x1, y1):
                fully_visible.append(index)
        reach = _DISTRACTOR_REACH
        for pose in scene.distractors:
            if self.overlaps(pose.x - reach, pose.y - reach, pose.x + reach, pose.y + reach):
                xs, ys = placed_vertices(DISTRACTOR_VERTICES, pose)
                self.polygon(DISTRACTOR_OUTLINE, pose.angle, xs, ys, palette.distractor)
        self.agent(scene.agent)
        for wall in geometry.drawn_walls:
            self.rectangle(wall, palette.wall)
        return fully_visible


class ViewRenderer:
    """Draws the agent's view box into an ``obs_size`` x ``obs_size`` x 3 uint8 observation."""

    def __init__(self, obs_size: int, canvas_size: int, view_size: int):
        self.obs_size, self.canvas_size = obs_size, canvas_size
        image = np.empty((canvas_size, canvas_size, 3), dtype=np.uint8)
        self._canvas = _Canvas(image, canvas_size / view_size, VIEW_PALETTE)

    def draw(self, scene: Scene, geometry: ArenaGeometry,
             box: ViewBox) -> tuple[np.ndarray, list[int]]:
        """The observation, and the indices of the objects completely inside the view box."""
        fully_visible = self._canvas.draw(scene, geometry, (box.x0, box.y0), box)
        image = self._canvas.image
        if self.canvas_size == self.obs_size:
            return image.copy(), fully_visible
        size = (self.obs_size, self.obs_size)
        return cv2.resize(image, size, interpolation=cv2.INTER_AREA), fully_visible


def draw_arena(scene: Scene, geometry: ArenaGeometry, box: ViewBox) -> np.ndarray:
    """The full arena at 1 px per world unit with the grey overlay on the view box."""
    image = np.empty((geometry.length, geometry.width, 3), dtype=np.uint8)
    _Canvas(image, 1.0, SCREEN_PALETTE, centre_sampled=False).draw(scene, geometry, (0.0, 0.0),
                                                                   box)
    view = image[box.y0:box.y0 + box.size, box.x0:box.x0 + box.size].astype(np.int32)
    view += ((OVERLAY_GREY - view) * OVERLAY_ALPHA + 128) >> 8
    image[box.y0:box.y0 + box.size, box.x0:box.x0 + box.size] = view
    return image


def original_pipeline_view(scene: Scene, geometry: ArenaGeometry, box: ViewBox,
                           obs_size: int = 64) -> np.ndarray:
    """An emulation of the original's observation, to compare against (tests, benchmark).

    The original draws the view box at 1 px per world unit with pygame (inclusive fills) and
    resizes that 250x250 frame with ``cv2.INTER_LINEAR`` (spec 3.6). Here the frame is drawn
    like ``draw_arena`` (cv2's inclusive rule, in the in-view colours) and resized the same way.
    """
    image = np.empty((box.size, box.size, 3), dtype=np.uint8)
    _Canvas(image, 1.0, VIEW_PALETTE, centre_sampled=False).draw(scene, geometry,
                                                                 (box.x0, box.y0), box)
    return cv2.resize(image, (obs_size, obs_size), interpolation=cv2.INTER_LINEAR)
