"""BringBackShapes benchmark: agent steps/s, reset time, memory, vector scaling, time split.

Per configuration (distractors, arena scale), single process, random actions, action repeat 4,
64x64 observations, medians over ``REPEATS`` runs:

* ``steps/s``: ``env.step`` in a loop (resets at episode ends included), against the original
  release's rates measured on the 2-core reference machine;
* ``reset``: ``env.reset(seed=...)`` time;
* ``physics`` / ``drawing``: the same agent steps with only the physics (4 sub-steps) or only
  the drawing of the observation (recorded scenes), so the rest is bookkeeping;
* ``memory``: resident memory added per environment (20 environments built and reset).

Then a 2-process ``AsyncVectorEnv`` against one process, the drawing-backend comparison that
chose OpenCV (``cv2.fillConvexPoly``, as is and with the observation's shrunk edges, against a
vectorised numpy half-plane rasteriser, on the same polygons), and the drawing's fidelity:

* drawn area of every shape at 64x64 over random sub-pixel placements and angles, against its
  true area (the polygon's or disc's, times (64/250)^2); a pixel counts the fraction of the way
  from the background to the shape's colour. For the observation, for cv2's inclusive fill at
  64x64 (the drawing before pixel-centre sampling) and for the emulated original pipeline;
* the share of observation pixels that differ from the emulated original pipeline (the scene
  drawn at 250x250 with the inclusive rule, then ``cv2.INTER_LINEAR`` to 64x64).

Run: ``python -m experiments.bench.bench_bbs``.
"""

from __future__ import annotations

import datetime
import os
import statistics
import time
from pathlib import Path

import cv2
import gymnasium
import numpy as np
import psutil

import bbs
from bbs.geometry import AGENT_RADIUS, DISTRACTOR_VERTICES, OBJECT_SHAPES
from bbs.physics import Pose
from bbs.render import (
    OBJECT_OUTLINES,
    VIEW_PALETTE,
    ViewRenderer,
    _Canvas,
    original_pipeline_view,
    placed_vertices,
    view_box,
)

RESULTS = Path(__file__).parent / "results" / "bbs.md"
CONFIGS = ((0, 1.0), (2, 1.0), (0, 1.4), (4, 1.0))
ORIGINAL_STEPS_PER_S = {(0, 1.0): 129, (2, 1.0): 90, (0, 1.4): 116, (4, 1.0): 70}
REPEATS = 5
STEPS = 1500
RESETS = 50
PLACEMENTS = 200  # per shape, for the drawn areas
DIFF_SEEDS, DIFF_STEPS = 10, 60  # bbs_basic_d2 episodes and steps for the pixel differences
# The previous drawing (cv2's inclusive fill directly at 64x64) against the emulated original
# pipeline on the same scenes, measured 2026-12-01 before the change.
PREVIOUS_DIFF_SHARE = 0.0215


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (n, 2)).astype(np.float32)


def _median_rates(run, n: int) -> tuple[float, float]:
    """Medians of ``n / seconds`` over ``REPEATS`` calls of ``run``: wall clock, process CPU."""
    wall, cpu = [], []
    for _ in range(REPEATS):
        start_wall, start_cpu = time.perf_counter(), time.process_time()
        run()
        wall.append(n / (time.perf_counter() - start_wall))
        cpu.append(n / (time.process_time() - start_cpu))
    return statistics.median(wall), statistics.median(cpu)


def _median_rate(run, n: int) -> float:
    return _median_rates(run, n)[0]


def steps_per_second(distractors: int, scale: float) -> tuple[float, float]:
    env = bbs.BringBackShapesEnv(num_distractors=distractors, arena_scale=scale)
    env.reset(seed=0)
    actions = _actions(STEPS)

    def run():
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()

    return _median_rates(run, STEPS)


def reset_ms(distractors: int, scale: float) -> float:
    env = bbs.BringBackShapesEnv(num_distractors=distractors, arena_scale=scale)
    wall, cpu = _median_rates(lambda: [env.reset(seed=s) for s in range(RESETS)], RESETS)
    return 1e3 / wall, 1e3 / cpu


def physics_and_drawing_rates(distractors: int, scale: float) -> tuple[float, float]:
    """CPU-time agent steps/s of the physics alone and of the drawing alone (recorded scenes)."""
    env = bbs.BringBackShapesEnv(num_distractors=distractors, arena_scale=scale, time_limit=None)
    env.reset(seed=0)
    sim, rng = env.unwrapped._sim, env.np_random
    controls = [(float((a0 + 1) * np.pi), float((a1 + 1) * 200)) for a0, a1 in _actions(STEPS)]

    def physics():
        for angle, force in controls:
            for _ in range(env.action_repeat):
                sim.control_and_score(angle, force, rng)
                sim.advance()

    scenes = []
    for action in _actions(STEPS, seed=1):
        env.step(action)
        scenes.append(env.scene)
    renderer, geometry = env.unwrapped._renderer, sim.geometry
    boxes = [view_box(s.agent, env.agent_view_size, geometry) for s in scenes]

    def drawing():
        for scene, box in zip(scenes, boxes, strict=True):
            renderer.draw(scene, geometry, box)

    return _median_rates(physics, STEPS)[1], _median_rates(drawing, STEPS)[1]


def memory_mb_per_env(distractors: int, scale: float, count: int = 50) -> float:
    process = psutil.Process()
    before = process.memory_info().rss
    envs = [bbs.BringBackShapesEnv(num_distractors=distractors, arena_scale=scale)
            for _ in range(count)]
    for i, env in enumerate(envs):
        env.reset(seed=i)
        env.step(_actions(1)[0])
    return (process.memory_info().rss - before) / count / 2**20


def vector_scaling(steps: int = 1000) -> tuple[float, float, float]:
    """Total agent steps/s: one plain env, ``AsyncVectorEnv`` of 1 and of 2 processes.

    The 1-process vector env isolates gymnasium's inter-process overhead from the scaling.
    """
    actions = _actions(steps * 2).reshape(steps, 2, 2)
    single = bbs.make("bbs_basic")
    single.reset(seed=0)

    def run_single():
        for a in actions[:, 0]:
            _, _, terminated, truncated, _ = single.step(a)
            if terminated or truncated:
                single.reset()

    rates = [_median_rate(run_single, steps)]
    for num_envs in (1, 2):
        envs = gymnasium.vector.AsyncVectorEnv([lambda: bbs.make("bbs_basic")] * num_envs)
        envs.reset(seed=list(range(num_envs)))
        batch = actions[:, :num_envs]
        rates.append(_median_rate(lambda e=envs, b=batch: [e.step(a) for a in b],
                                  steps * num_envs))
        envs.close()
    return tuple(rates)


def _numpy_fill_convex(image: np.ndarray, points: list[tuple[float, float]], colour) -> None:
    """Vectorised half-plane rasteriser (pixel centres inside a counter-clockwise polygon)."""
    pts = np.asarray(points)
    x0, y0 = np.maximum(np.floor(pts.min(0)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(pts.max(0)).astype(int) + 1, image.shape[1::-1])
    if x0 >= x1 or y0 >= y1:
        return
    ys, xs = np.mgrid[y0:y1, x0:x1]
    start, end = pts, np.roll(pts, -1, axis=0)
    cross = ((end[:, 0, None, None] - start[:, 0, None, None]) * (ys - start[:, 1, None, None])
             - (end[:, 1, None, None] - start[:, 1, None, None]) * (xs - start[:, 0, None, None]))
    inside = np.all(cross >= 0, axis=0) | np.all(cross <= 0, axis=0)
    image[y0:y1, x0:x1][inside] = colour


def drawing_backends(repeats: int = 2000) -> dict[str, float]:
    """Microseconds to fill the 5 object shapes (in view, 64x64 image) with each backend."""
    scale = 64 / 250
    poses = [Pose(150.0 + 40 * i, 200.0, 0.3 * i) for i in range(len(OBJECT_SHAPES))]
    placed = [placed_vertices(local, pose)
              for local, pose in zip(OBJECT_SHAPES.values(), poses, strict=True)]
    polygons = [[((x - 100) * scale, (y - 100) * scale) for x, y in zip(xs, ys, strict=True)]
                for xs, ys in placed]
    fixed = [np.rint(np.array(p) * 256).astype(np.int32) for p in polygons]
    image = np.zeros((64, 64, 3), np.uint8)
    canvases = [_Canvas(image, scale, VIEW_PALETTE, centre_sampled=c) for c in (False, True)]
    for canvas in canvases:
        canvas._set_origin(100.0, 100.0)
    outlines = [OBJECT_OUTLINES[name] for name in OBJECT_SHAPES]

    def opencv():
        for p in fixed:
            cv2.fillConvexPoly(image, p, (1, 2, 3), cv2.LINE_8, 8)

    def canvas_polygons(canvas):  # world vertices converted (and edges shrunk) on every call
        for outline, pose, (xs, ys) in zip(outlines, poses, placed, strict=True):
            canvas.polygon(outline, pose.angle, xs, ys, (1, 2, 3))

    def numpy_rasteriser():
        for p in polygons:
            _numpy_fill_convex(image, p, (1, 2, 3))

    backends = (("cv2.fillConvexPoly", opencv),
                ("with vertex conversion (the previous drawing)",
                 lambda: canvas_polygons(canvases[0])),
                ("with vertex conversion and shrunk edges (the observation's)",
                 lambda: canvas_polygons(canvases[1])),
                ("numpy half-planes", numpy_rasteriser))
    return {name: 1e6 / _median_rate(lambda f=f: [f() for _ in range(repeats)], repeats)
            for name, f in backends}


def _area_and_centroid(vertices) -> tuple[float, tuple[float, float]]:
    area2 = cx = cy = 0.0
    for (x0, y0), (x1, y1) in zip(vertices, (*vertices[1:], vertices[0]), strict=True):
        cross = x0 * y1 - x1 * y0
        area2, cx, cy = area2 + cross, cx + (x0 + x1) * cross, cy + (y0 + y1) * cross
    return abs(area2) / 2, (cx / (3 * area2), cy / (3 * area2))


def _drawn_area(obs: np.ndarray, colour, box, centre, reach: float = 45.0) -> float:
    """px^2 of ``colour`` near ``centre``: each pixel's fraction from background to colour."""
    background = np.array(VIEW_PALETTE.background, float)
    direction = np.array(colour, float) - background
    share = np.clip((obs - background) @ direction / (direction @ direction), 0.0, 1.0)
    centres = (np.arange(obs.shape[0]) + 0.5) * box.size / obs.shape[0] - 0.5
    near_x = np.abs(centres + box.x0 - centre[0]) < reach
    near_y = np.abs(centres + box.y0 - centre[1]) < reach
    return float(share[np.outer(near_y, near_x)].sum())


AREA_KINDS = (*OBJECT_SHAPES, "agent", "distractor")


def drawn_area_ratios() -> dict[str, dict[str, tuple[float, float, float]]]:
    """Per drawing and shape: mean, min and max of drawn / true area over random placements.

    Each shape alone, its centroid at a random point of a 8x8 px square, at a random angle
    (the agent: its centre, which the view follows).
    """
    env = bbs.BringBackShapesEnv()
    inclusive = _Canvas(np.empty((64, 64, 3), np.uint8), 64 / 250, VIEW_PALETTE,
                        centre_sampled=False)
    far = {"position": (140.0, 140.0), "angle": 0.0, "shape": "triangle", "colour": "red"}
    ratios = {"observation": {}, "inclusive fill at 64x64": {}, "original pipeline": {}}
    for kind in AREA_KINDS:
        rng = np.random.default_rng(0)
        samples = {name: [] for name in ratios}
        for _ in range(PLACEMENTS):
            angle = float(rng.uniform(0, 2 * np.pi))
            cx, cy = (float(v) for v in rng.uniform(-4, 4, 2) + (250.0, 310.0))
            scene = {"agent": {"position": (330.0, 380.0)}, "objects": [far]}
            if kind == "agent":
                scene["agent"] = {"position": (cx, cy), "angle": angle}
                area, colour = np.pi * AGENT_RADIUS**2, VIEW_PALETTE.agent
            else:
                vertices = DISTRACTOR_VERTICES if kind == "distractor" else OBJECT_SHAPES[kind]
                area, (gx, gy) = _area_and_centroid(vertices)
                c, s = np.cos(angle), np.sin(angle)
                origin = (cx - (c * gx - s * gy), cy - (s * gx + c * gy))
                if kind == "distractor":
                    scene["distractors"] = [{"position": origin, "angle": angle}]
                    colour = VIEW_PALETTE.distractor
                else:
                    scene["objects"] = [{"position": origin, "angle": angle, "shape": kind,
                                         "colour": "red"}]
                    colour = VIEW_PALETTE.objects["red"]
            obs, _ = env.reset(options={"layout": scene})
            geometry, box = env.geometry, view_box(env.scene.agent, 125, env.geometry)
            inclusive.draw(env.scene, geometry, (box.x0, box.y0), box)
            images = (obs, inclusive.image, original_pipeline_view(env.scene, geometry, box))
            for name, image in zip(ratios, images, strict=True):
                drawn = _drawn_area(image, colour, box, (cx, cy))
                samples[name].append(drawn / (area * (64 / 250) ** 2))
        for name, values in samples.items():
            ratios[name][kind] = (float(np.mean(values)), min(values), max(values))
    return ratios


def pixel_difference_share() -> tuple[float, float, int]:
    """Mean and largest share of observation pixels that differ from the emulated original,
    and how many differing pixels lie neither on an edge of the emulated frame (a 3x3
    neighbourhood of one colour) nor on the agent's orientation line."""
    line = ViewRenderer(64, 64, 250)._canvas.agent_line
    shares, off_edge = [], 0
    for seed in range(DIFF_SEEDS):
        env = bbs.make("bbs_basic_d2")
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for step in range(DIFF_STEPS):
            obs, *_ = env.step(rng.uniform(-1, 1, 2))
            if step % 6 != 5:
                continue
            box = view_box(env.scene.agent, 125, env.geometry)
            reference = original_pipeline_view(env.scene, env.geometry, box)
            differs = np.any(obs != reference, axis=-1)
            shares.append(float(differs.mean()))
            padded = np.pad(reference, ((1, 1), (1, 1), (0, 0)), mode="edge")
            windows = np.lib.stride_tricks.sliding_window_view(padded, (3, 3), axis=(0, 1))
            on_edge = np.any(windows.max(axis=(-2, -1)) != windows.min(axis=(-2, -1)), axis=-1)
            on_edge |= np.all(obs == line, axis=-1)
            off_edge += int((differs & ~on_edge).sum())
    return float(np.mean(shares)), max(shares), off_edge


def _fidelity_lines(ratios, diff_mean: float, diff_max: float, off_edge: int) -> list[str]:
    header = "| drawing | " + " | ".join(AREA_KINDS) + " |"
    lines = [header, "|---|" + "---|" * len(AREA_KINDS)]
    for name, per_kind in ratios.items():
        cells = [f"{mean:.3f} ({low:.2f}–{high:.2f})" for mean, low, high in per_kind.values()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return [
        f"Drawn area / true area at 64x64, mean (min–max) over {PLACEMENTS} random placements "
        "per shape (sub-pixel position and angle; the agent sits at the view centre, so only "
        "its centre's sub-pixel phase varies). Drawn area sums, per pixel, the fraction of the "
        "way from the background to the shape's colour; the true area is the polygon's (disc's) "
        "area times (64/250)^2. `inclusive fill` is cv2's rule straight at 64x64, the drawing "
        "before pixel-centre sampling; `original pipeline` is the emulation below.",
        "",
        *lines,
        "",
        f"Against the emulated original pipeline (the scene drawn at 250x250 with the inclusive "
        f"rule, `cv2.INTER_LINEAR` to 64x64), {DIFF_SEEDS} `bbs_basic_d2` episodes, every 6th "
        f"of {DIFF_STEPS} steps: {100 * diff_mean:.2f}% of observation pixels differ (largest "
        f"frame {100 * diff_max:.2f}%); {off_edge} of them lie neither on an edge nor on the "
        f"agent's orientation line. With the previous drawing {100 * PREVIOUS_DIFF_SHARE:.2f}%.",
    ]


def main() -> None:
    rows = []
    for distractors, scale in CONFIGS:
        wall, cpu = steps_per_second(distractors, scale)
        physics, drawing = physics_and_drawing_rates(distractors, scale)
        original = ORIGINAL_STEPS_PER_S[(distractors, scale)]
        reset_wall, reset_cpu = reset_ms(distractors, scale)
        rows.append(
            f"| {distractors} | {scale} | {original} | {wall:,.0f} ({wall / original:.0f}x) | "
            f"{cpu:,.0f} ({cpu / original:.0f}x) | {1e6 / cpu:.0f} | {1e6 / physics:.0f} | "
            f"{1e6 / drawing:.0f} | {reset_wall:.2f} / {reset_cpu:.2f} | "
            f"{memory_mb_per_env(distractors, scale):.2f} |"
        )
        print(rows[-1], flush=True)
    single, async_one, async_two = vector_scaling()
    backends = drawing_backends()
    load = os.getloadavg()[0]
    ratios = drawn_area_ratios()
    diff_mean, diff_max, off_edge = pixel_difference_share()
    text = "\n".join([
        "## BringBackShapes environment (`bbs`)",
        "",
        f"Single process, random actions, action repeat 4, 64x64 observations, median of "
        f"{REPEATS} runs of {STEPS} agent steps (resets included). `wall` is wall-clock "
        "steps/s; `CPU` divides by the process's CPU time instead, which is what the code "
        "costs when the machine is shared (load average at the end of this run: "
        f"{load:.1f} on {os.cpu_count()} cores). µs columns are CPU time per agent step: "
        "`physics` is the 4 sub-steps alone, `drawing` the observation alone, the rest of "
        "`step` is bookkeeping (actions, scene read-out, discovery, info). `original` is the "
        "released version's wall-clock rate on the quiet reference machine.",
        "",
        "| distractors | scale | original steps/s | wall steps/s | CPU steps/s | step µs | "
        "physics µs | drawing µs | reset ms (wall / CPU) | MB/env |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        f"Vector env (`bbs_basic`, total agent steps/s, wall clock): plain env {single:,.0f}; "
        f"`AsyncVectorEnv` of 1 process {async_one:,.0f} (gymnasium's pipe round trip per "
        f"step); of 2 processes {async_two:,.0f}, {async_two / async_one:.2f}x the 1-process "
        "vector env.",
        "",
        "Drawing backend, 5 object polygons into a 64x64 image: "
        + ", ".join(f"{name} {us:.1f} µs" for name, us in backends.items()) + ".",
        "",
        *_fidelity_lines(ratios, diff_mean, diff_max, off_edge),
        "",
    ])
    from experiments.bench.run_all import machine_line  # imports jax: after the timings

    title, _, body = text.partition("\n")
    stamp = f"_Measured {datetime.date.today().isoformat()} on {machine_line()}._"
    text = f"{title}\n\n{stamp}\n{body}"
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
