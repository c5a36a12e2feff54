"""``python -m vsgjax.evaluate LOGDIR``: run a training run's newest checkpoint (actor mode).

    python -m vsgjax.evaluate runs/bbs_basic-vsg-s0 --episodes 10
    python -m vsgjax.evaluate runs/bbs_basic-vsg-s0 --episodes 50 --output evaluation.jsonl

``--output`` writes one JSON object per episode and line, as the trainer's
``eval_episodes.jsonl`` (NaN written as ``null``), atomically once every episode has run.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vsgjax.analysis.evaluation import evaluate_logdir, format_table, write_episodes
from vsgjax.config.checks import RANGES
from vsgjax.outdir import OutputDirError, check_output_dir


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vsgjax.evaluate", description=__doc__.split(
        "\n")[0])
    parser.add_argument("logdir", type=Path, help="a training run's log directory")
    parser.add_argument("--episodes", type=int, default=None,
                        help="episodes to run (default: the run's train.eval_episodes)")
    parser.add_argument("--seed", type=int, default=None,
                        help="evaluation env seed (default: the run's seed)")
    parser.add_argument("--output", type=Path, default=None, metavar="PATH",
                        help="also write the episodes as JSON lines to PATH (atomically)")
    args = parser.parse_args(argv)
    try:
        check_args(args)
        infos, env_steps = evaluate_logdir(args.logdir, args.episodes, args.seed)
    except (FileNotFoundError, ValueError) as error:  # ConfigError, OutputDirError too
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"{args.logdir}: checkpoint at env step {env_steps}, {len(infos)} episodes, "
          "actor mode")
    print(format_table(infos))
    if args.output is not None:
        try:
            path = write_episodes(args.output, infos, env_steps)
        except OSError as error:  # a WriteError names the path
            print(f"error: {error}", file=sys.stderr)
            return 1
        print(f"wrote {len(infos)} episodes to {path}")
    return 0


def check_args(args: argparse.Namespace) -> None:
    """ValueError naming the flag of a value no evaluation can use (before any runs)."""
    if args.episodes is not None and args.episodes < 1:
        raise ValueError(f"--episodes {args.episodes}: valid: an integer >= 1")
    if args.seed is not None and args.seed not in RANGES["train.seed"]:
        raise ValueError(f"--seed {args.seed}: valid: an integer in {RANGES['train.seed']}")
    if args.output is not None:
        if args.output.is_dir():
            raise OutputDirError(f"--output {args.output} is a directory; valid: a file path")
        check_output_dir(args.output.parent, "--output's directory")


if __name__ == "__main__":
    sys.exit(main())
