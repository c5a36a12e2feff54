"""BringBackShapes benchmark: agent steps/s, reset time, memory, vector scaling, time split.

Per configuration (distractors, arena scale), single process, random actions, action repeat 4,
64x64 observations, medians over ``REPEATS`` runs:

* ``steps/s``: ``env.step`` in a loop (resets at episode ends included), against the original
  release's rates measured on the 2-core reference machine;
* ``reset``: ``env.reset(seed=...)`` time;
* ``physics`` / ``drawing``: the same agent steps with only the physics (4 sub-steps) or only
  the drawing of the observation (recorded scenes), so the rest is bookkeeping;
* ``memory``: resident memory added per environment (20 environments built and reset).

Then a 2-process ``AsyncVectorEnv`` against one process, and the drawing-backend comparison
that chose OpenCV: ``cv2.fillConvexPoly`` against a vectorised numpy half-plane rasteriser, on
the same polygons. Run: ``python -m experiments.bench.bench_bbs``.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import cv2
import gymnasium
import numpy as np
import psutil

import bbs
from bbs.render import placed_vertices, view_box

RESULTS = Path(__file__).parent / "results" / "bbs.md"
CONFIGS = ((0, 1.0), (2, 1.0), (0, 1.4), (4, 1.0))
ORIGINAL_STEPS_PER_S = {(0, 1.0): 129, (2, 1.0): 90, (0, 1.4): 116, (4, 1.0): 70}
REPEATS = 5
STEPS = 1500
RESETS = 50


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
    from bbs.geometry import OBJECT_SHAPES
    from bbs.physics import Pose

    scale = 64 / 250
    placed = [placed_vertices(local, Pose(150.0 + 40 * i, 200.0, 0.3 * i))
              for i, local in enumerate(OBJECT_SHAPES.values())]
    polygons = [[((x - 100) * scale, (y - 100) * scale) for x, y in zip(xs, ys, strict=True)]
                for xs, ys in placed]
    fixed = [np.rint(np.array(p) * 256).astype(np.int32) for p in polygons]
    image = np.zeros((64, 64, 3), np.uint8)

    def opencv():
        for p in fixed:
            cv2.fillConvexPoly(image, p, (1, 2, 3), cv2.LINE_8, 8)

    def numpy_rasteriser():
        for p in polygons:
            _numpy_fill_convex(image, p, (1, 2, 3))

    backends = (("cv2.fillConvexPoly", opencv), ("numpy half-planes", numpy_rasteriser))
    return {name: 1e6 / _median_rate(lambda f=f: [f() for _ in range(repeats)], repeats)
            for name, f in backends}


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
    ])
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
