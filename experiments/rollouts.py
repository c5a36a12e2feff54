"""The paper's imagined-rollout figure and, for VSG / SVSG, the gate heatmap.

    python -m experiments.rollouts runs/bbs_basic-vsg-s0 [--out DIR] [--episode N]
        [--context 15] [--horizon 35] [--samples 5] [--seed S]

From the run's newest checkpoint and one stored episode (``--episode``: an index into
``episodes/``, oldest first, negative from the newest; default the newest episode long enough),
the world model observes the first ``context`` frames (posterior states, shown as their
reconstructions) and then imagines ``horizon`` frames open loop under the episode's recorded
actions, ``samples`` times from the same context. The grid has one row of ground truth, then
one row per sample, and ``context + horizon`` frame columns (a line marks where imagination
starts). For gated models a second figure shows, for the first sample, which units opened at
each step (units x time; the posterior's gates during the context, the prior's during
imagination) and beneath it the fraction of units open per step (that sample, and the mean
over samples). Models without gates get the grid only, and a note.

The same test as numbers: the prediction error at each imagined step, of the observations
(pixels in [0, 1]) and of the rewards, averaged over the samples drawn
(:func:`vsgjax.agents.dreamer.open_loop.open_loop_errors`, the function training logs to
``open_loop.jsonl`` at every evaluation); printed at imagined steps 5, 15 and 35.

Files (default ``--out``: ``<LOGDIR>/rollouts/``): ``open_loop-ep<N>.png/.pdf``,
``gates-ep<N>.png/.pdf`` and ``rollouts-ep<N>.npz`` (the figure data, with the errors as
``obs_mse`` and ``reward_mse`` [horizon]).

:func:`rollout_data` returns the figure data (arrays) and :func:`draw_grid` /
:func:`draw_gates` draw it, so tests and notebooks can use the data without drawing.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import vsgjax
from vsgjax.agents.dreamer import api
from vsgjax.agents.dreamer.open_loop import ERROR_INPUTS, open_loop_errors
from vsgjax.analysis.load import TrainedRun
from vsgjax.loop.rundir import OPEN_LOOP_STEPS

CONTEXT = 15
HORIZON = 35
SAMPLES = 5
GAP = 2  # pixels between frames in the grid


@dataclass
class RolloutData:
    """What the figures show.

    ``frames`` uint8 [1 + samples, context + horizon, H, W, C]: row 0 the ground truth, then
    one row per sample (reconstructions during the context, imagination after it).
    ``gates`` [units, context + horizon] of 0/1 for the first sample (None without gates),
    ``gate_fraction`` [samples, context + horizon] the fraction of units open per step.
    ``rewards`` [1 + samples, context + horizon]: recorded, then predicted rewards.
    ``obs_mse`` and ``reward_mse`` [horizon]: the error at each imagined step, averaged over
    the samples shown (:func:`vsgjax.agents.dreamer.open_loop.open_loop_errors`; entry k - 1
    is imagined step k, against episode step context + k - 1).
    """

    frames: np.ndarray
    gates: np.ndarray | None
    gate_fraction: np.ndarray | None
    rewards: np.ndarray
    context: int
    horizon: int
    episode: int
    step: int  # the checkpoint's env step
    model: str
    obs_mse: np.ndarray | None = None
    reward_mse: np.ndarray | None = None

    def arrays(self) -> dict[str, np.ndarray]:
        out = {"frames": self.frames, "rewards": self.rewards, "context": self.context,
               "horizon": self.horizon, "episode": self.episode, "step": self.step}
        if self.obs_mse is not None:
            out.update(obs_mse=self.obs_mse, reward_mse=self.reward_mse)
        if self.gates is not None:
            out.update(gates=self.gates, gate_fraction=self.gate_fraction)
        return out


def pick_episode(run: TrainedRun, length: int, index: int | None = None) -> tuple[int, dict]:
    """(index, episode): episode ``index``, or the newest one of at least ``length`` steps."""
    paths = run.episode_paths()
    if not paths:
        raise FileNotFoundError(f"no episodes in {run.logdir / 'episodes'}")
    if index is not None:
        if not -len(paths) <= index < len(paths):
            raise IndexError(f"--episode {index} out of range: {run.logdir / 'episodes'} holds "
                             f"{len(paths)} episodes")
        index %= len(paths)
        episode = run.episode(index)
        if len(episode["image"]) < length:
            raise ValueError(f"episode {index} has {len(episode['image'])} steps, fewer than "
                             f"context + horizon = {length}")
        return index, episode
    for index in reversed(range(len(paths))):
        episode = run.episode(index)
        if len(episode["image"]) >= length:
            return index, episode
    raise ValueError(f"no episode in {run.logdir / 'episodes'} has context + horizon = "
                     f"{length} steps")


def rollout_data(run: TrainedRun, episode: dict, *, context: int = CONTEXT, horizon: int = HORIZON,
                 samples: int = SAMPLES, key: jax.Array | None = None,
                 episode_index: int = -1) -> RolloutData:
    """The figure data of one episode (see :class:`RolloutData`).

    The keys are used as :func:`vsgjax.agents.dreamer.open_loop.open_loop_frames` uses them,
    so the frames equal
    those of the run's open-loop video for the same key.
    """
    length = context + horizon
    if context < 1 or horizon < 1 or samples < 1:
        raise ValueError(f"context, horizon and samples must be >= 1, got {context}, "
                         f"{horizon}, {samples}")
    if len(episode["image"]) < length:
        raise ValueError(f"episode of {len(episode['image'])} steps is shorter than "
                         f"context + horizon = {length}")
    key = jax.random.PRNGKey(0) if key is None else key
    seq = {k: jnp.repeat(jnp.asarray(episode[k][None, :length]), samples, axis=0)
           for k in ("image", "action", "is_first")}
    observe_key, imagine_key = jax.random.split(key)
    posts = run.observe({k: v[:, :context] for k, v in seq.items()}, observe_key)
    start = jax.tree.map(lambda x: x[:, -1], posts)
    imagined = api.imagine(run.params, start, horizon, key=imagine_key,
                           actions=seq["action"][:, context:].astype(jnp.float32))
    predicted = np.concatenate([np.asarray(run.decode(posts)),
                                np.asarray(imagined["images"])], axis=1)
    frames = np.concatenate([np.asarray(episode["image"][None, :length]), predicted], axis=0)
    rewards = np.concatenate([np.asarray(run.reward(posts)),
                              np.asarray(imagined["rewards"])], axis=1)
    rewards = np.concatenate([np.asarray(episode["reward"][None, :length], np.float32),
                              rewards], axis=0)
    gates = fraction = None
    if run.gated:
        post_gates, _ = jax.vmap(jax.vmap(run.dynamics.gates))(posts)
        prior_gates, _ = jax.vmap(jax.vmap(run.dynamics.gates))(imagined["states"])
        every = np.concatenate([np.asarray(post_gates), np.asarray(prior_gates)], axis=1)
        every = every.reshape(every.shape[:2] + (-1,))  # [samples, time, units]
        gates = every[0].T
        fraction = every.mean(-1)
    # the same key and the episode once per sample: the errors of the samples drawn above
    repeated = {k: np.repeat(np.asarray(episode[k][None, :length]), samples, 0)
                for k in (*run.agent.obs_shape.keys, *ERROR_INPUTS)}
    errors = jax.device_get(open_loop_errors(run.config, run.params.wm, repeated, key, context,
                                             horizon))
    return RolloutData(frames, gates, fraction, rewards, context, horizon, episode_index,
                       run.step, run.config.agent, np.asarray(errors["obs_mse"]),
                       np.asarray(errors["reward_mse"]))


def errors_line(data: RolloutData) -> str:
    """``open-loop MSE at imagined step 5: obs 0.0123, reward 0.0456; ...``."""
    parts = [f"{k}: obs {data.obs_mse[k - 1]:.4g}, reward {data.reward_mse[k - 1]:.4g}"
             for k in OPEN_LOOP_STEPS if k <= data.horizon]
    return "open-loop MSE at imagined step " + "; ".join(parts)


def tile(frames: np.ndarray, gap: int = GAP) -> np.ndarray:
    """[rows, cols, H, W, C] uint8 -> one [rows·(H+gap)-gap, cols·(W+gap)-gap, C] image, white
    gaps between frames."""
    rows, cols, height, width, channels = frames.shape
    image = np.full((rows * (height + gap) - gap, cols * (width + gap) - gap, channels), 255,
                    np.uint8)
    for r in range(rows):
        for c in range(cols):
            y, x = r * (height + gap), c * (width + gap)
            image[y:y + height, x:x + width] = frames[r, c]
    return image


def draw_grid(data: RolloutData, title: str | None = None):
    """The paper's grid: ground truth, then the samples; a line where imagination starts."""
    from matplotlib.figure import Figure

    rows, cols, height, width = data.frames.shape[:4]
    image = tile(data.frames)
    if image.shape[-1] == 1:
        image = np.repeat(image, 3, -1)
    left, right, top, bottom = 0.75, 0.1, 0.35, 0.3  # margins, inches
    width_in = 0.42 * cols
    height_in = width_in * image.shape[0] / image.shape[1]
    fig_w, fig_h = left + width_in + right, bottom + height_in + top
    fig = Figure(figsize=(fig_w, fig_h), dpi=150)
    ax = fig.add_axes((left / fig_w, bottom / fig_h, width_in / fig_w, height_in / fig_h))
    ax.imshow(image, interpolation="nearest")
    x = data.context * (width + GAP) - GAP / 2 - 0.5
    ax.axvline(x, color="red", linewidth=1.2)
    ax.set_yticks([r * (height + GAP) + height / 2 for r in range(rows)],
                  ["True"] + [f"Sample {i}" for i in range(1, rows)], fontsize=7)
    ticks = [t for t in range(0, cols, 5)]
    ax.set_xticks([t * (width + GAP) + width / 2 for t in ticks], [str(t) for t in ticks],
                  fontsize=6)
    ax.tick_params(length=0)
    for side in ax.spines.values():
        side.set_visible(False)
    ax.set_title(title or (f"{data.model}: {data.context} context + {data.horizon} imagined "
                           "frames (open loop, recorded actions)"), fontsize=8)
    return fig


def draw_gates(data: RolloutData, title: str | None = None):
    """Units x time heatmap of the first sample's gates (dark = open), and the fraction of
    units open per step beneath (that sample, and the mean over samples)."""
    from matplotlib.figure import Figure

    if data.gates is None:
        raise ValueError(f"model {data.model!r} has no gates")
    units, steps = data.gates.shape
    fig = Figure(figsize=(max(6.0, 0.16 * steps + 1.5), 4.2), dpi=150)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1))
    top.imshow(data.gates, aspect="auto", cmap="Greys", vmin=0, vmax=1, interpolation="nearest")
    top.set_ylabel(f"unit ({units})", fontsize=8)
    top.set_title(title or (f"{data.model}: gates of sample 1 (dark = open; posterior during "
                            "the context, prior in imagination)"), fontsize=8)
    time = np.arange(steps)
    bottom.plot(time, data.gate_fraction[0], color="black", linewidth=1, label="sample 1")
    if len(data.gate_fraction) > 1:
        bottom.plot(time, data.gate_fraction.mean(0), color="tab:blue", linewidth=1,
                    alpha=0.7, label=f"mean of {len(data.gate_fraction)} samples")
    bottom.set_ylim(0, 1)
    bottom.set_ylabel("open", fontsize=8)
    bottom.set_xlabel("step", fontsize=8)
    bottom.legend(fontsize=6, loc="upper right")
    for ax in (top, bottom):
        ax.axvline(data.context - 0.5, color="red", linewidth=1)
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig


def save(fig, stem: Path) -> list[Path]:
    """``stem``.png and ``stem``.pdf."""
    paths = [stem.with_suffix(".png"), stem.with_suffix(".pdf")]
    for path in paths:
        fig.savefig(path)
    return paths


def make_rollouts(logdir: str | Path, out: str | Path | None = None, *,
                  episode: int | None = None, context: int = CONTEXT, horizon: int = HORIZON,
                  samples: int = SAMPLES, seed: int = 0, say=print
                  ) -> tuple[RolloutData, list[Path]]:
    """Load the run, compute the figure data, draw and save it -> (data, written paths)."""
    run = vsgjax.load(logdir)
    index, chosen = pick_episode(run, context + horizon, episode)
    data = rollout_data(run, chosen, context=context, horizon=horizon, samples=samples,
                        key=jax.random.PRNGKey(seed), episode_index=index)
    out = Path(logdir) / "rollouts" if out is None else Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = save(draw_grid(data), out / f"open_loop-ep{index}")
    if data.gates is not None:
        written += save(draw_gates(data), out / f"gates-ep{index}")
    else:
        say(f"note: model {data.model!r} has no gates; no gate heatmap")
    npz = out / f"rollouts-ep{index}.npz"
    np.savez_compressed(npz, **data.arrays())
    written.append(npz)
    say(errors_line(data))
    return data, written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.rollouts",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("logdir", type=Path, help="a training run's log directory")
    parser.add_argument("--out", type=Path, default=None, help="default: LOGDIR/rollouts")
    parser.add_argument("--episode", type=int, default=None,
                        help="episode index in episodes/ (oldest first, negative from the "
                             "newest); default: the newest with context + horizon steps")
    parser.add_argument("--context", type=int, default=CONTEXT)
    parser.add_argument("--horizon", type=int, default=HORIZON)
    parser.add_argument("--samples", type=int, default=SAMPLES)
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed of the samples")
    args = parser.parse_args(argv)
    try:
        data, written = make_rollouts(args.logdir, args.out, episode=args.episode,
                                      context=args.context, horizon=args.horizon,
                                      samples=args.samples, seed=args.seed)
    except (FileNotFoundError, ValueError, IndexError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"{args.logdir}: checkpoint at env step {data.step}, episode {data.episode}, "
          f"{data.context} + {data.horizon} frames, {len(data.frames) - 1} samples")
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
