"""Peak memory and time of the full agent update per size and host allocator.

The full update (world model + imagination actor-critic, ``DreamerAgent.train_step``, batch 16 x 50,
BBS presets) runs ``UPDATES`` times in a fresh process per (size, allocator); the parent
samples the child's resident memory every 50 ms and stops it above ``RSS_LIMIT_GIB`` (this
machine has 24 GiB: a child that keeps every freed byte was OOM-killed at 24.3 GiB at the
``paper`` size), so a row that hit the limit says so instead of taking the machine down::

    python -m experiments.bench.bench_memory                  # small and paper (~10 min)
    python -m experiments.bench.bench_memory --sizes small

Allocators: glibc; mimalloc keeping every freed byte (``MIMALLOC_PURGE_DELAY=-1``, the setting
of earlier sessions); mimalloc returning memory unused for ``PURGE_DELAYS`` ms (100 ms is what
:mod:`vsgjax.allocator` sets).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from vsgjax.allocator import allocator_env, glibc_env, mimalloc_library

UPDATES = 4
RSS_LIMIT_GIB = 20.0
PURGE_DELAYS = (-1, 1000, 100)  # ms; -1 keeps everything
RESULTS = Path(__file__).parent / "results" / "memory.md"


def measure(size: str) -> dict:
    """In the child: compile and run the full agent update; median time, faults, peak RSS."""
    import jax

    from experiments.bench.bench_agent import replay_batch
    from vsgjax.agents import make_agent
    from vsgjax.config import make_config
    from vsgjax.envs import EnvSpec

    config = make_config("bbs_basic", "vsg", size, ["train.batch=16", "train.length=50"])
    agent = make_agent(config, EnvSpec((64, 64, 3), 2, False))
    state = agent.init(jax.random.PRNGKey(0))
    batch = replay_batch(config, 2)
    times, faults = [], []
    for update in range(UPDATES + 1):  # the first call compiles
        usage = resource.getrusage(resource.RUSAGE_SELF)
        started = time.perf_counter()
        state, metrics = agent.train_step(state, batch, jax.random.PRNGKey(update))
        jax.block_until_ready(metrics)
        if update:
            times.append(time.perf_counter() - started)
            faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - usage.ru_minflt)
    return {"update_s": statistics.median(times), "faults": statistics.median(faults),
            "peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def allocators() -> dict[str, dict[str, str]]:
    """Name -> environment of every allocator setting measured."""
    base = glibc_env(dict(os.environ))
    settings = {"glibc": base}
    if mimalloc_library() is not None:
        for delay in PURGE_DELAYS:
            name = "mimalloc, keep all" if delay < 0 else f"mimalloc, purge after {delay} ms"
            settings[name] = {**base, **allocator_env(), "MIMALLOC_PURGE_DELAY": str(delay)}
    return settings


def _rss(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def run_child(size: str, env: dict[str, str]) -> dict:
    """The child's answer, or ``{"limit": peak}`` when it passed ``RSS_LIMIT_GIB``."""
    root = Path(__file__).resolve().parents[2]
    env = dict(env, PYTHONPATH=str(root), JAX_PLATFORMS="cpu")
    child = subprocess.Popen([sys.executable, "-m", "experiments.bench.bench_memory",
                              "--child", size], cwd=root, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    peak, limit = 0, RSS_LIMIT_GIB * 2**30
    while child.poll() is None:
        peak = max(peak, _rss(child.pid))
        if peak > limit:
            child.kill()
            child.wait()
            return {"limit": peak}
        time.sleep(0.05)
    out, err = child.communicate()
    if child.returncode != 0:
        raise RuntimeError(f"bench_memory child {size} failed:\n{err[-3000:]}")
    return json.loads(out.strip().splitlines()[-1])


def markdown(rows: list[tuple[str, str, dict]]) -> str:
    lines = ["## Memory of the full agent update (host allocator)", "",
             f"`DreamerAgent.train_step` (world model + actor + critic), VSG, BBS presets, "
             f"batch 16 x 50, "
             f"median of {UPDATES} updates after the compiling one, one fresh process per row; "
             f"peak RSS from `getrusage` (a row stopped by the parent above {RSS_LIMIT_GIB:.0f} "
             "GiB says so). `faults` = minor page faults per update.", "",
             "| size | allocator | update (s) | page faults / update | peak RSS GiB |",
             "|---|---|---|---|---|"]
    for size, name, r in rows:
        if "limit" in r:
            lines.append(f"| {size} | {name} | - | - | stopped above {r['limit'] / 2**30:.1f} |")
        else:
            lines.append(f"| {size} | {name} | {r['update_s']:.2f} | {r['faults']:,.0f} | "
                         f"{r['peak_rss'] / 2**30:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench.bench_memory")
    parser.add_argument("--sizes", nargs="+", default=["small", "paper"])
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(measure(args.child)))
        return
    rows = []
    for size in args.sizes:
        for name, env in allocators().items():
            rows.append((size, name, run_child(size, env)))
            print(size, name, rows[-1][2], flush=True)
    RESULTS.write_text(markdown(rows))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
