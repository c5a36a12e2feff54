"""Mixed precision (``model.precision``, ``vsgjax/agents/precision.py``): one jitted agent update
(``DreamerAgent.train_step``: world model + imagination actor-critic) at the ``small`` size, float32
against bfloat16, on BBS shapes (batch 16 x 50 of 64x64x3 images).

Medians over ``REPEATS`` calls after compilation, wall and process-CPU seconds (``bench_agent``'s
helpers). bfloat16 is not expected to pay off on a CPU (XLA:CPU's bfloat16 products are no
faster than its float32 ones, plus the casts; the 2-core development VM was measured slower);
the mode is meant for GPUs, where bfloat16 halves the matmul inputs and runs on tensor cores.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import jax

from experiments.bench import bench_agent
from vsgjax.agents import make_agent
from vsgjax.config import PRECISIONS, make_config
from vsgjax.envs import EnvSpec

MODELS = ("vsg",)
RESULTS = Path(__file__).parent / "results" / "precision.md"


def bench_update(model: str, precision: str) -> dict:
    config = make_config("bbs_basic", model, "small", [f"model.precision={precision}"])
    agent, key = make_agent(config, EnvSpec((64, 64, 3), 2, False)), jax.random.PRNGKey(0)
    batch, state = bench_agent.replay_batch(config, 2), agent.init(key)
    compile_s = bench_agent.compile_seconds(agent.train_step, agent, state, batch, key)
    agent.train_step(state, batch, key)  # populate the call cache (compiled above)
    wall, cpu = bench_agent.median_times(lambda: agent.train_step(state, batch, key))
    return {"model": model, "precision": precision, "wall": wall, "cpu": cpu,
            "compile": compile_s}


def markdown(rows: list[dict]) -> str:
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    lines = [
        "## Mixed precision (`model.precision`, agent update, small size, BBS batch 16 x 50)",
        "",
        f"Median of {bench_agent.REPEATS} jitted `DreamerAgent.train_step` calls after "
        "compilation; "
        "wall / process-CPU seconds. bfloat16: matmul and convolution inputs in bfloat16, "
        "float32 accumulation, parameters and everything else; bfloat16 is not expected to "
        f"pay off on a CPU. Load average at the end: {load}.",
        "",
        "| model | float32 s | bfloat16 s | bfloat16 / float32 (CPU) | compile s (f32 / bf16) |",
        "|---|---|---|---|---|",
    ]
    by_key = {(r["model"], r["precision"]): r for r in rows}
    for model in dict.fromkeys(r["model"] for r in rows):
        f32, bf16 = by_key[model, "float32"], by_key[model, "bfloat16"]
        lines.append(
            f"| {model} | {f32['wall']:.2f} / {f32['cpu']:.2f} | "
            f"{bf16['wall']:.2f} / {bf16['cpu']:.2f} | {bf16['cpu'] / f32['cpu']:.2f}x | "
            f"{f32['compile']:.0f} / {bf16['compile']:.0f} |")
    return "\n".join(lines) + "\n"


def main(models: tuple[str, ...] = MODELS) -> None:
    text = markdown([bench_update(model, precision) for model in models
                     for precision in PRECISIONS])
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main(tuple(sys.argv[1:]) or MODELS)
