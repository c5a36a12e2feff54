"""World-model update time, compile time, memory, FLOP rate; imagination throughput.

Each configuration runs in its own subprocess (so peak RSS is per configuration)::

    python -m experiments.bench.bench_world_model                 # everything (~15 min, 2 cores)
    python -m experiments.bench.bench_world_model --sizes small   # skip the paper size
    python -m experiments.bench.bench_world_model --resume        # finish an interrupted run

Measured, at batch 16 x length 50 with 64x64x3 images (BBS presets):

* one jitted world-model update (forward, backward, AdamW): median wall time over ``--updates``
  calls after compilation; the compile time; XLA's buffer sizes and the process's peak RSS;
* its FLOPs counted from the jaxpr (:mod:`experiments.bench.flops`: matmuls and convolutions,
  scan bodies multiplied by their length) next to XLA's ``cost_analysis()`` figure, which
  counts each scan body once; the FLOP rate achieved as a fraction of a large float32 matmul's;
* a breakdown of the update into encoder / dynamics / decoder+heads (each forward+backward),
  with the rate each part reaches: the profile that says where time goes;
* ``imagine`` throughput (start states x horizon per second) from 800 start states, H = 15;
* the host allocator's effect: the profiled model's update again in a process on glibc's
  malloc instead of mimalloc (:mod:`vsgjax.allocator`), with page faults and kernel time
per update.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from vsgjax.allocator import allocator_active, allocator_env, glibc_env

RESULTS = Path(__file__).parent / "results" / "world_model.md"
# every child's answer is also appended here, so an interrupted run keeps what it measured
PARTIAL = Path(__file__).parent / "results" / "world_model_partial.jsonl"
MODELS = ("vsg", "svsg", "dreamerv2")
DECODED_MODEL = "vsg"
BATCH, LENGTH, START_STATES, HORIZON = 16, 50, 800, 15


@contextlib.contextmanager
def lax_convolutions():
    """Trace the networks with XLA's own convolutions instead of the matmul formulations.

    The model computes its convolutions as matmuls over patches, which includes multiplying
    padding and zero kernel taps; the useful FLOPs are counted on the equivalent lax
    convolutions (for which :mod:`experiments.bench.flops` counts useful multiply-adds only).
    The stride-2 layers bind their op when their class is created (``apply_op``), so the
    classes are patched, not the module-level functions.
    """
    from jax import lax

    from vsgjax.agents.dreamer import networks

    def flat(fn):
        def apply(x, kernel, dtype=None):  # the FLOP count does not depend on the dtype
            y = fn(x.reshape((-1,) + x.shape[-3:]), kernel)
            return y.reshape(x.shape[:-3] + y.shape[1:])
        return staticmethod(apply)

    dims = ("NHWC", "HWIO", "NHWC")
    layers = networks.Conv2, networks.ConvTranspose2
    saved = [layer.__dict__["apply_op"] for layer in layers]
    networks.Conv2.apply_op = flat(
        lambda x, k: lax.conv_general_dilated(x, k, (2, 2), "VALID", dimension_numbers=dims))
    networks.ConvTranspose2.apply_op = flat(
        lambda x, k: lax.conv_transpose(x, k[::-1, ::-1], (2, 2), "VALID", dimension_numbers=dims))
    try:
        yield
    finally:
        for layer, op in zip(layers, saved, strict=True):
            layer.apply_op = op


def model_flops(fn, *args) -> dict[str, int]:
    """Matmul + convolution FLOPs of ``fn(*args)`` (not jitted: no stale trace cache):
    ``useful`` (the model's work, convolutions as lax convolutions) and ``matmul_form`` (what
    the matmul formulation multiplies, zero taps and padding included)."""
    from experiments.bench.flops import count_flops

    matmul_form = count_flops(fn, *args)
    with lax_convolutions():
        return {"useful": count_flops(fn, *args), "matmul_form": matmul_form}


def _timed(fn, *args, repeats: int) -> list[float]:
    import jax

    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return times


def matmul_rate(size: int = 2048, repeats: int = 10) -> float:
    """FLOP/s of a ``size``^2 float32 matmul in JAX (median of ``repeats``)."""
    import jax
    import jax.numpy as jnp

    a = jax.random.normal(jax.random.PRNGKey(0), (size, size), jnp.float32)
    matmul = jax.jit(jnp.matmul)
    jax.block_until_ready(matmul(a, a))
    return 2 * size**3 / statistics.median(_timed(matmul, a, a, repeats=repeats))


def _batch(config, seed: int = 0) -> dict:
    import numpy as np

    rng = np.random.default_rng(seed)
    is_first = np.zeros((BATCH, LENGTH), bool)
    is_first[:, 0] = True
    return {
        "image": rng.integers(0, 256, (BATCH, LENGTH, 64, 64, 3), dtype=np.uint8),
        "action": rng.uniform(-1, 1, (BATCH, LENGTH, 2)).astype(np.float32),
        "reward": rng.normal(size=(BATCH, LENGTH)).astype(np.float32),
        "is_first": is_first,
        "is_terminal": np.zeros((BATCH, LENGTH), bool),
    }


def _config(model: str, size: str):
    from vsgjax.config import make_config

    return make_config("bbs_basic", model, size,
                       [f"train.batch={BATCH}", f"train.length={LENGTH}"])


def measure_update(model: str, size: str, updates: int) -> dict:
    """Compile and time the world-model update of one configuration (run in a subprocess)."""
    import jax

    from vsgjax.agents.dreamer import api

    config = _config(model, size)
    state = api.init(config, jax.random.PRNGKey(0))
    batch = _batch(config)
    key = jax.random.PRNGKey(1)
    start = time.perf_counter()
    compiled = api.world_model_step.lower(config, state, batch, key).compile()
    compile_s = time.perf_counter() - start
    memory = compiled.memory_analysis()
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    flops = model_flops(lambda s, b, k: api.world_model_step.__wrapped__(config, s, b, k),
                        state, batch, key)
    times = []
    usage = resource.getrusage(resource.RUSAGE_SELF)
    for i in range(updates):
        start = time.perf_counter()
        state, metrics, _ = compiled(state, batch, jax.random.PRNGKey(i))
        jax.block_until_ready(state)
        times.append(time.perf_counter() - start)
    after = resource.getrusage(resource.RUSAGE_SELF)
    return {
        "model": model, "size": size, "params": sum(x.size for x in jax.tree.leaves(state.params)),
        "compile_s": compile_s, "update_s": statistics.median(times),
        "update_min_s": min(times), "flops": flops["useful"],
        "matmul_form_flops": flops["matmul_form"], "xla_flops": cost.get("flops", float("nan")),
        "temp_bytes": memory.temp_size_in_bytes,
        "arg_bytes": memory.argument_size_in_bytes, "out_bytes": memory.output_size_in_bytes,
        "peak_rss": after.ru_maxrss * 1024,
        "loss": float(metrics["loss"]),
        "faults_per_update": (after.ru_minflt - usage.ru_minflt) / updates,
        "kernel_s_per_update": (after.ru_stime - usage.ru_stime) / updates,
        "mimalloc": allocator_active(),
    }


def measure_breakdown(model: str, size: str, repeats: int) -> list[dict]:
    """Forward+backward time and FLOPs of the update's parts (the profile of one update)."""
    import jax
    import jax.numpy as jnp

    from vsgjax.agents.dreamer import api
    from vsgjax.agents.dreamer.networks import image_to_float, normal_log_prob
    from vsgjax.agents.dreamer.world_model import WorldModel

    config = _config(model, size)
    wm = WorldModel(config)
    params = api.init(config, jax.random.PRNGKey(0)).params
    batch = _batch(config)
    images = batch["image"].reshape(BATCH * LENGTH, 64, 64, 3)
    embeds = wm.encode(params, images).reshape(BATCH, LENGTH, -1)
    keys = jax.random.split(jax.random.PRNGKey(1), BATCH)
    feats = jnp.zeros((BATCH * LENGTH, wm.dynamics.feat_dim))
    dyn = wm.dynamics

    def encoder(p):
        return jnp.square(wm.encode(p, images)).mean()

    def dynamics(p):
        def one(embed, action, first, key):
            posts, priors = dyn.observe(p["dynamics"], embed, action, first, key)
            return jax.vmap(dyn.kl)(posts, priors).sum() + jax.vmap(dyn.feat)(posts).sum()
        return jax.vmap(one)(embeds, batch["action"], batch["is_first"], keys).mean()

    def decoder_and_heads(p):
        target = image_to_float(images)
        image = normal_log_prob(wm.representation.decode(p, feats), target, event_dims=3).mean()
        return image + wm.reward_mean(p, feats).mean() + wm.discount_logits(p, feats).mean()

    rows = []
    for name, fn in (("encoder", encoder), ("dynamics (observe scan)", dynamics),
                     ("decoder + heads", decoder_and_heads)):
        grad = jax.jit(jax.grad(fn))
        jax.block_until_ready(grad(params))
        seconds = statistics.median(_timed(grad, params, repeats=repeats))
        flops = model_flops(jax.grad(fn), params)
        rows.append({"part": name, "seconds": seconds, "flops": flops["useful"],
                     "matmul_form_flops": flops["matmul_form"]})
    return rows


def measure_imagine(model: str, size: str, repeats: int) -> dict:
    """Latent imagination (the actor-critic's rollout) and ``api.imagine`` with decoding."""
    import jax
    import jax.numpy as jnp

    from vsgjax.agents.dreamer import api
    from vsgjax.agents.dreamer.world_model import WorldModel

    config = _config(model, size)
    wm = WorldModel(config)
    params = api.init(config, jax.random.PRNGKey(0)).params
    dyn = wm.dynamics
    start = jax.tree.map(lambda x: jnp.broadcast_to(x, (START_STATES,) + x.shape), dyn.initial())
    keys = jax.random.split(jax.random.PRNGKey(2), START_STATES)

    def policy(feat, key):
        return jnp.tanh(feat[:2])

    latent = jax.jit(jax.vmap(lambda s, k: dyn.imagine(params["dynamics"], policy, s, HORIZON,
                                                       k)[0]))
    jax.block_until_ready(latent(start, keys))
    latent_s = statistics.median(_timed(latent, start, keys, repeats=repeats))

    steps = START_STATES * HORIZON
    result = {"model": model, "size": size, "latent_steps_per_s": steps / latent_s,
              "decoded_steps_per_s": float("nan")}
    if model == DECODED_MODEL:  # decoding dominates and costs the same for every model

        def decoded(s, k):
            return api.imagine(params, s, HORIZON, config=config, key=k, action_dim=2)["images"]

        jax.block_until_ready(decoded(start, keys[0]))
        result["decoded_steps_per_s"] = steps / min(_timed(decoded, start, keys[0], repeats=1))
    return result


def _run_child(*args: str, glibc: bool = False) -> dict | list:
    """Run this module with ``args`` in a fresh process; return its JSON answer.

    It runs on mimalloc (:mod:`vsgjax.allocator`) unless ``glibc`` (the allocator comparison).
    """
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env = glibc_env(env) if glibc else dict(env, **allocator_env())
    out = subprocess.run([sys.executable, "-m", "experiments.bench.bench_world_model", *args],
                         capture_output=True, text=True, env=env, cwd=root, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"bench child {args} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _partial_results() -> dict[tuple[str, str, str], dict | list]:
    """{(kind, model, size): result} of the children an earlier run finished."""
    if not PARTIAL.exists():
        return {}
    lines = [json.loads(line) for line in PARTIAL.read_text().splitlines() if line.strip()]
    return {tuple(line["job"]): line["result"] for line in lines if "job" in line}


def _mib(n: float) -> str:
    return f"{n / 2**20:,.0f}"


def report(rate: float, updates: list[dict], breakdown: list[dict], imagine: list[dict],
           allocator: list[tuple[dict, dict]], load: tuple[float, float, float], args) -> str:
    lines = [
        "## World model (CORE-WM)",
        "",
        f"Update = forward + backward + AdamW of the world-model loss, batch {BATCH} x length "
        f"{LENGTH}, 64x64x3 images, BBS presets, float32. Median of {args.updates} updates after "
        f"compilation. Load average when the run started: {load[0]:.1f} / {load[1]:.1f} / "
        f"{load[2]:.1f} (other processes share these cores: a load above the core count slows "
        "every figure).",
        "",
        f"Reference: a 2048x2048 float32 matmul in JAX reaches **{rate / 1e9:.1f} GFLOP/s**.",
        "",
        "Host allocator of every child process: "
        + ("mimalloc (`vsgjax/allocator.py`)." if updates and updates[0]["mimalloc"]
           else "the C library's (mimalloc is not installed)."),
        "",
        "FLOPs = matmul + convolution FLOPs of the update counted from its jaxpr, every scan "
        "body multiplied by its length. `useful` counts the convolutions as the lax "
        "convolutions they equal, without multiplications by padding or inserted zeros: the "
        "model's work, from which GFLOP/s and % of matmul are computed. `matmul form` counts "
        "what the matmul formulation the model runs multiplies (zero taps and padding "
        "included). `XLA` = `compiled.cost_analysis()['flops']`, which counts each scan body "
        "once (and includes elementwise work).",
        "",
        "| model | size | params | update (s) | compile (s) | GFLOP useful | GFLOP matmul form | "
        "XLA GFLOP | useful GFLOP/s | % of matmul | XLA temp MiB | peak RSS MiB | "
        "page faults / update |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in updates:
        achieved = r["flops"] / r["update_s"]
        lines.append(
            f"| {r['model']} | {r['size']} | {r['params'] / 1e6:.1f}M | {r['update_s']:.3f} | "
            f"{r['compile_s']:.1f} | {r['flops'] / 1e9:.1f} | "
            f"{r['matmul_form_flops'] / 1e9:.1f} | {r['xla_flops'] / 1e9:.1f} | "
            f"{achieved / 1e9:.1f} | {100 * achieved / rate:.0f}% | {_mib(r['temp_bytes'])} | "
            f"{_mib(r['peak_rss'])} | {r['faults_per_update']:,.0f} |")
    if breakdown:
        lines += ["", f"Where the time goes ({args.profile_model}, {args.profile_size}; each part "
                  "forward + backward alone, median):", "",
                  "| part | seconds | GFLOP useful | GFLOP matmul form | useful GFLOP/s | "
                  "% of matmul |", "|---|---|---|---|---|---|"]
        for r in breakdown:
            achieved = r["flops"] / r["seconds"]
            lines.append(f"| {r['part']} | {r['seconds']:.3f} | {r['flops'] / 1e9:.1f} | "
                         f"{r['matmul_form_flops'] / 1e9:.1f} | {achieved / 1e9:.1f} | "
                         f"{100 * achieved / rate:.0f}% |")
    if allocator:
        lines += ["", "Host allocator: the same update in a process on glibc's malloc (no "
                  "`LD_PRELOAD`) against mimalloc above (`vsgjax/allocator.py`); kernel time "
                  "is the "
                  "process's system CPU time (both cores), mostly zero-filling faulted pages.", "",
                  "| model | size | update (s) glibc | mimalloc | speed-up | page faults / update "
                  "glibc | mimalloc | kernel s / update glibc | mimalloc |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for default, tuned in allocator:
            lines.append(
                f"| {tuned['model']} | {tuned['size']} | {default['update_s']:.3f} | "
                f"{tuned['update_s']:.3f} | {default['update_s'] / tuned['update_s']:.2f}x | "
                f"{default['faults_per_update']:,.0f} | {tuned['faults_per_update']:,.0f} | "
                f"{default['kernel_s_per_update']:.2f} | {tuned['kernel_s_per_update']:.2f} |")
    if imagine:
        lines += ["", f"Imagination from {START_STATES} start states, horizon {HORIZON} "
                  "(start states x horizon per second): latent rollout under a policy (what the "
                  "actor-critic runs) and `vsgjax.imagine` including decoding every frame "
                  f"(measured for {DECODED_MODEL} only: decoding dominates and is the same "
                  "network for every model).", "",
                  "| model | size | latent steps/s | decoded steps/s |", "|---|---|---|---|"]
        for r in imagine:
            lines.append(f"| {r['model']} | {r['size']} | {r['latent_steps_per_s']:,.0f} | "
                         f"{r['decoded_steps_per_s']:,.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["small", "paper"])
    parser.add_argument("--models", nargs="+", default=list(MODELS))
    parser.add_argument("--updates", type=int, default=10)
    parser.add_argument("--profile-model", default="vsg")
    parser.add_argument("--profile-size", default="paper")
    parser.add_argument("--no-profile", action="store_true")
    parser.add_argument("--imagine-size", default="paper")
    parser.add_argument("--no-imagine", action="store_true")
    parser.add_argument("--no-allocator", action="store_true",
                        help="skip the comparison with glibc's malloc")
    parser.add_argument("--resume", action="store_true",
                        help="reuse the measurements an interrupted run left in "
                             f"{PARTIAL.name} (the reference matmul is measured again)")
    parser.add_argument("--child", nargs=3, metavar=("KIND", "MODEL", "SIZE"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.child:
        kind, model, size = args.child
        jobs = {"update": lambda: measure_update(model, size, args.updates),
                "breakdown": lambda: measure_breakdown(model, size, max(3, args.updates // 2)),
                "imagine": lambda: measure_imagine(model, size, 3)}
        jobs["update-glibc"] = jobs["update"]  # the same measurement; its parent drops mimalloc
        answer = json.dumps(jobs[kind]())
        with PARTIAL.open("a") as log:
            log.write(json.dumps({"job": [kind, model, size], "result": json.loads(answer)})
                      + "\n")
        print(answer)
        return
    if not args.resume:
        PARTIAL.unlink(missing_ok=True)
    done = _partial_results() if args.resume else {}

    def measured(kind: str, model: str, size: str) -> dict | list:
        if (kind, model, size) in done:
            return done[(kind, model, size)]
        return _run_child("--child", kind, model, size, "--updates", str(args.updates),
                          glibc=kind == "update-glibc")

    load = os.getloadavg()
    rate = matmul_rate()
    updates = [measured("update", m, s) for s in args.sizes for m in args.models]
    breakdown = [] if args.no_profile else measured("breakdown", args.profile_model,
                                                    args.profile_size)
    allocator = [] if args.no_allocator or not allocator_env() else [
        (measured("update-glibc", args.profile_model, size),
         next(r for r in updates if r["model"] == args.profile_model and r["size"] == size))
        for size in args.sizes if args.profile_model in args.models]
    imagine = [] if args.no_imagine else [
        measured("imagine", m, args.imagine_size) for m in args.models]
    text = report(rate, updates, breakdown, imagine, allocator, load, args)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
