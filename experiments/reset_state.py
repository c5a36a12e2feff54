"""How much of the observation the memoryless control's state keeps (docs/mjx.md).

    python -m experiments.reset_state RUN_DIR [RUN_DIR ...] [--episodes 4] [--seed S]

For each run (vector observations, a model with a decoder) and its newest ``--episodes``
stored episodes, the world model's decoder predicts each step's observation from two states:
the posterior carried along the episode, and the posterior of that step's observation alone
(:func:`vsgjax.agents.dreamer.agent.posteriors_alone`, what ``ac.memoryless`` acts from). It
prints, per observation dimension and on average, the fraction of the observation's variance
the prediction leaves unexplained (mean squared error / variance, over the steps after each
episode's first, where the two states are the same).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import vsgjax
from vsgjax.agents.dreamer.agent import posteriors_alone
from vsgjax.agents.dreamer.world_model import WorldModel

STATES = ("carried", "alone")


def squared_errors(model: WorldModel, wm_params: dict, episode: dict,
                   key: jax.Array) -> dict[str, np.ndarray]:
    """``{"carried" | "alone": [T, D]}``: the decoder's squared error of the episode's vector
    observation (its vector keys concatenated in key order) from each state."""
    obs = {name: jnp.asarray(episode[name]) for name in model.obs_shape.keys}
    seq = {**obs, "action": jnp.asarray(episode["action"], jnp.float32),
           "is_first": jnp.asarray(episode["is_first"])}
    carry_key, alone_key = jax.random.split(key)
    carried, _ = model.observe(wm_params, seq, carry_key)
    alone = posteriors_alone(model.dynamics, wm_params["dynamics"], model.encode(wm_params, obs),
                             seq["action"].shape[-1], alone_key)
    target = model.vector_input(obs)
    errors = {}
    for name, states in zip(STATES, (carried, alone), strict=True):
        predicted = model.vector_input(
            model.representation.decode_vectors(wm_params, jax.vmap(model.dynamics.feat)(states)))
        errors[name] = np.asarray((predicted - target) ** 2)
    return errors


def unexplained_fractions(run, episodes: int, seed: int = 0) -> dict[str, np.ndarray]:
    """``{"carried" | "alone": [D]}`` over the run's newest ``episodes`` (first steps left
    out), and ``"variance"``: the observation's variance [D] over the same steps."""
    model, params = run.world_model, run.params.wm
    if model.has_image or not model.vector_keys or not model.representation.decodes:
        raise ValueError(f"run {run.logdir} observes {model.obs_shape.shapes} with model "
                         f"{run.config.agent!r}: reset_state needs vector observations "
                         "only and a model with a decoder")
    stored = run.episodes(episodes)
    if not stored:
        raise FileNotFoundError(f"no episodes in {run.logdir / 'episodes'}")
    errors = {name: [] for name in STATES}
    targets = []
    for index, episode in enumerate(stored):
        later = ~np.asarray(episode["is_first"], bool)
        for name, error in squared_errors(model, params, episode,
                                          jax.random.PRNGKey(seed + index)).items():
            errors[name].append(error[later])
        targets.append(np.asarray(model.vector_input(episode))[later])
    variance = np.concatenate(targets).var(0)
    out = {name: np.concatenate(parts).mean(0) / variance for name, parts in errors.items()}
    return {**out, "variance": variance}


def _row(values: np.ndarray) -> str:
    return " ".join(f"{value:.3f}" for value in values)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.reset_state",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("logdirs", type=Path, nargs="+", help="training runs' log directories")
    parser.add_argument("--episodes", type=int, default=4, help="newest episodes per run")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed of the state samples")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        print(f"error: --episodes {args.episodes}; valid: >= 1", file=sys.stderr)
        return 2
    for logdir in args.logdirs:
        try:
            fractions = unexplained_fractions(vsgjax.load(logdir), args.episodes, args.seed)
        except (FileNotFoundError, ValueError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        print(f"{logdir}: unexplained fraction of the observation's variance per dimension "
              f"(variance {_row(fractions['variance'])})")
        for name in STATES:
            print(f"  {name:8s} {_row(fractions[name])}  mean {fractions[name].mean():.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
