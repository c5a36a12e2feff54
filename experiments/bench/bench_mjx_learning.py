"""Learning curves of VSG on MJX tasks with the device loop: return vs env steps and wall time.

What ``make train TASK=<task>`` runs on this machine (``small`` VSG on the CPU, the device
loop, the dmc preset's schedule), to ``--steps`` env steps, evaluated every ``--eval-every``
env steps (``train.eval_episodes`` episodes with the actor's mode). Wall time counts from the
trainer's construction, so it includes compilation and prefill: it is the wait a user sees.
Each task's reference is a uniform random policy's return over ``RANDOM_EPISODES`` episodes.

    python -m experiments.bench.bench_mjx_learning [--tasks T ...] [--steps N] [--size S]

Writes ``results/mjx_learning.md`` and ``docs/figures/mjx_learning.png``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from experiments.bench.run_all import ROOT, machine_line
from vsgjax.config import make_config
from vsgjax.envs.mjx import make_mjx_task
from vsgjax.envs.mjx.random_policy import random_returns
from vsgjax.train import make_trainer

TASKS = ("mjx_cartpole_swingup", "mjx_cheetah_run")
MODEL, RANDOM_EPISODES, EVAL_EPISODES = "vsg", 32, 4
RESULTS = Path(__file__).parent / "results" / "mjx_learning.md"
FIGURE = ROOT / "docs" / "figures" / "mjx_learning.png"


def learning_curve(task: str, size: str, steps: int, eval_every: int) -> dict:
    """Train one seed; ``{"steps", "seconds", "returns"}`` at every evaluation."""
    config = make_config(task, MODEL, size, [
        f"train.steps={steps}", f"train.eval_every={eval_every}",
        f"train.eval_episodes={EVAL_EPISODES}", "train.ckpt_every=1000000000"])
    curve = {"steps": [], "seconds": [], "returns": [], "config": config}
    with tempfile.TemporaryDirectory() as logdir:
        started = time.monotonic()
        trainer = make_trainer([config], [Path(logdir)], progress=False)
        evaluate = trainer.evaluate

        def timed_evaluate():
            evaluate()
            run = trainer.runs[0]
            curve["steps"].append(trainer.env_steps)
            curve["seconds"].append(time.monotonic() - started)
            curve["returns"].append(run.scores["ys"][-1])

        trainer.evaluate = timed_evaluate
        try:
            trainer.run()
        finally:
            trainer.close()
    return curve


def random_reference(task: str, config) -> tuple[float, float]:
    """Mean and standard deviation of a random policy's return on ``task``."""
    env = config.env
    returns = np.asarray(random_returns(make_mjx_task(task, env.action_repeat, env.time_limit),
                                        RANDOM_EPISODES, jax.random.PRNGKey(0)))
    return float(returns.mean()), float(returns.std())


def markdown(curves: dict, randoms: dict, size: str) -> str:
    config = next(iter(curves.values()))["config"]
    train = config.train
    lines = [f"## MJX learning curves ({size} VSG, device loop)", "",
             f"_Measured {time.strftime('%Y-%m-%d')} on {machine_line()}._", "",
             f"One seed per task, the `make train` defaults at size `{size}`: "
             f"{config.env.num_envs} env(s), batch {train.batch} x {train.length}, one update "
             f"per {train.train_every} agent steps, prefill {train.prefill} env steps, "
             f"{train.pretrain} pretraining updates; eval: {EVAL_EPISODES} episodes, actor's "
             f"mode. Wall time from the trainer's start (compilation and prefill included). "
             f"Random: uniform actions, {RANDOM_EPISODES} episodes (mean ± std).", "",
             "| task | random | env steps | wall s | eval return |", "|---|---|---|---|---|"]
    for task, curve in curves.items():
        mean, std = randoms[task]
        for step, seconds, value in zip(curve["steps"], curve["seconds"], curve["returns"],
                                        strict=True):
            lines.append(f"| {task} | {mean:.1f} ± {std:.1f} | {step:,} | {seconds:.0f} | "
                         f"{value:.1f} |")
    lines += ["", f"Figure: `docs/figures/{FIGURE.name}`."]
    return "\n".join(lines) + "\n"


def plot(curves: dict, randoms: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(curves), 2, figsize=(9, 3.2 * len(curves)), squeeze=False)
    for row, (task, curve) in zip(axes, curves.items(), strict=True):
        for ax, x, label in ((row[0], curve["steps"], "env steps"),
                             (row[1], np.asarray(curve["seconds"]) / 60, "wall minutes")):
            ax.plot(x, curve["returns"], marker="o", label="VSG (eval)")
            ax.axhline(randoms[task][0], color="gray", linestyle="--", label="random")
            ax.set(xlabel=label, ylabel="return", title=task)
            ax.grid(alpha=0.3)
        row[0].legend(loc="upper left")
    fig.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=110)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench.bench_mjx_learning",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--eval-every", type=int, default=1_000)
    parser.add_argument("--size", default="small")
    args = parser.parse_args(argv or [])
    curves = {task: learning_curve(task, args.size, args.steps, args.eval_every)
              for task in args.tasks}
    randoms = {task: random_reference(task, curve["config"]) for task, curve in curves.items()}
    text = markdown(curves, randoms, args.size)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    plot(curves, randoms)
    print(text)


if __name__ == "__main__":
    main(sys.argv[1:])
