"""Timing a jitted call for the benches: wall and process-CPU seconds, outputs ready.

Process CPU time is what the work costs when the machine is shared; wall time is what a run
waits for.
"""

from __future__ import annotations

import statistics
import time

import jax


def timed(fn, *args) -> tuple[float, float]:
    """(wall seconds, process CPU seconds) of one call, outputs ready."""
    wall, cpu = time.perf_counter(), time.process_time()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - wall, time.process_time() - cpu


def median_times(fn, repeats: int) -> tuple[float, float]:
    """Median (wall, process CPU) seconds of ``repeats`` calls of ``fn()``, outputs ready."""
    runs = [timed(fn) for _ in range(repeats)]
    return statistics.median(w for w, _ in runs), statistics.median(c for _, c in runs)
