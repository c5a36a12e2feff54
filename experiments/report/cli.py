"""``python -m experiments.report NAME``: an experiment's figures and tables beside the paper's.

The options are the launcher's (they select the same runs) plus ``--out`` and ``--bin``; see
docs/reports.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from experiments.report.assemble import build_report
from experiments.spec import ExperimentError, add_selection_arguments, load_experiment
from vsgjax.outdir import OutputDirError, check_output_dir


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.report",
                                     description=__doc__.split("\n")[0])
    add_selection_arguments(parser)  # the launch's options find the launch's runs
    parser.add_argument("--out", type=Path, default=None,
                        help="output directory (default: ROOT/NAME/report)")
    parser.add_argument("--bin", type=float, default=None,
                        help="grid spacing in env steps (default: the reference's grid)")
    args = parser.parse_args(argv)
    if args.bin is not None and args.bin <= 0:
        parser.error(f"--bin must be positive, got {args.bin:g}")
    try:
        experiment = load_experiment(args.name, args.size, args.seeds, args.steps,
                                     args.definitions)
        if args.out is not None:
            check_output_dir(args.out, "--out")
        else:
            check_output_dir(args.root, "--root")
    except (ExperimentError, OutputDirError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    report = build_report(experiment, args.root, args.out, spacing=args.bin,
                          definitions=args.definitions)
    print(f"{report.markdown}: {len(report.sections)} figures, "
          f"{len(report.missing)} of {len(experiment.runs)} runs missing, "
          f"{len(report.problems)} warnings")
    return 0
