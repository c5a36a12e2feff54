"""Launch an experiment's runs: ``python -m experiments.launch NAME [options]``.

A relaunch skips what is finished and resumes the rest; the options and the backends are in
docs/experiments.md.
"""

from __future__ import annotations

import argparse
import shlex
import sys

from experiments.launch.jobs import LaunchError, make_jobs
from experiments.launch.local import LocalRunner
from experiments.launch.process import default_backend, job_env
from experiments.launch.script import write_print
from experiments.launch.slurm import (
    INSTALL_SLURM,
    SUBMITIT_DIR,
    has_submitit,
    submit_slurm,
    wait_slurm,
)
from experiments.launch.status import Status, format_table, job_status
from experiments.spec import (
    PAPER_DIR,
    ExperimentError,
    add_selection_arguments,
    experiment_names,
    load_experiment,
)
from vsgjax.outdir import OutputDirError, check_output_dir

BACKENDS = ("local", "slurm", "print")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.launch", description=__doc__.split("\n")[0],
        epilog="See docs/experiments.md.")
    add_selection_arguments(parser)
    parser.add_argument("--backend", default="local", choices=BACKENDS)
    parser.add_argument("--jobs", type=int, default=None,
                        help="jobs at a time (local: processes, default 1, or with seeds spread "
                             "over host devices JOBS x seeds-per-process seeds; slurm / print: "
                             "the array's parallelism, default unlimited)")
    parser.add_argument("--status", action="store_true", help="print the table, launch nothing")
    parser.add_argument("--task", action="append", default=[],
                        help="only this task's runs (repeat or comma-separate)")
    parser.add_argument("--model", action="append", default=[],
                        help="only this model's runs (vsg, or vsg-<variant>; repeatable)")
    parser.add_argument("--seeds-per-process", type=int, default=None,
                        help="local: seeds of one task and method trained in one process "
                             "(default: the experiment's seeds_per_process, else 1); on a CPU "
                             "they are spread over as many forced host devices")
    parser.add_argument("--interval", type=float, default=None,
                        help="seconds between status tables (default 5 on a TTY, else 60)")
    slurm = parser.add_argument_group("slurm and print backends")
    slurm.add_argument("--partition", default=None)
    slurm.add_argument("--gpus-per-job", type=int, default=1)
    slurm.add_argument("--cpus-per-job", type=int, default=8)
    slurm.add_argument("--time", type=int, default=1440,
                       help="minutes per SLURM job before it is requeued (default 1440)")
    slurm.add_argument("--mem", type=float, default=None, help="GB per job")
    slurm.add_argument("--max-requeues", type=int, default=50,
                       help="timeouts after which a job is not requeued again (default 50)")
    slurm.add_argument("--signal-delay", type=int, default=None,
                       help="seconds before the time limit at which a job checkpoints and "
                            "requeues (submitit's default: 90)")
    slurm.add_argument("--cluster", default="slurm", choices=("slurm", "local"),
                       help="submitit's executor: slurm, or local to try the backend on this "
                            "machine")
    slurm.add_argument("--wait", action="store_true",
                       help="slurm: stay and show the table until the jobs end")
    args = parser.parse_args(argv)
    args.task = [t for value in args.task for t in value.split(",") if t]
    args.model = [m for value in args.model for m in value.split(",") if m]
    for option in ("jobs", "seeds_per_process"):
        value = getattr(args, option)
        if value is not None and value < 1:
            parser.error(f"--{option.replace('_', '-')} must be a positive integer, got {value}")
    return args


def main(argv: list[str] | None = None, out=None) -> int:
    out = out or sys.stdout
    args = parse_args(argv)
    root = args.root.absolute()
    try:
        names = experiment_names(args.definitions)
        if args.name not in names:
            raise LaunchError(f"unknown experiment {args.name!r}; valid: "
                              f"{', '.join(names) or f'none in {args.definitions}'}")
        experiment = load_experiment(args.name, args.size, args.seeds, args.steps,
                                     args.definitions)
        jobs = make_jobs(experiment, root, args.task, args.model)
        if args.backend == "slurm" and not args.status and not has_submitit():
            raise LaunchError(INSTALL_SLURM)
        if not args.status:
            check_output_dir(args.root, "--root")
    except (ExperimentError, LaunchError, OutputDirError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    statuses = {job.index: job_status(job) for job in jobs}
    if args.status or not jobs:
        out.write(format_table(jobs, statuses, {}) + "\n")
        return 0
    per_process = args.seeds_per_process or experiment.seeds_per_process
    if args.backend == "local":
        spread = per_process > 1 and default_backend(job_env(args.jobs or 1)) == "cpu"
        return LocalRunner(jobs, args.jobs or 1, args.interval, out,
                           seeds_per_process=per_process, spread=spread).run()
    if per_process > 1:
        out.write(f"note: the {args.backend} backend runs one seed per process "
                  f"(seeds_per_process {per_process} applies to the local backend)\n")
    todo = [job for job in jobs if statuses[job.index].launchable]
    out.write(format_table(jobs, statuses, {}) + "\n")
    if not todo:
        out.write("nothing to launch\n")
        return _exit_code(statuses)
    if args.backend == "print":
        commands, sbatch = write_print(todo, experiment, root, args)
        out.write(f"{len(todo)} commands: {commands}\nsbatch array script: {sbatch}\n")
        return 0
    try:
        submitted = submit_slurm(todo, experiment, root, args)
    except LaunchError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    ids = ", ".join(str(handle.job_id) for handle in submitted)
    out.write(f"submitted {len(submitted)} jobs ({ids}); submitit files in "
              f"{root / experiment.name / SUBMITIT_DIR}\n")
    if not args.wait:
        out.write(f"follow with: python -m experiments.launch {args.name} --status "
                  f"{_rebuild_flags(args)}\n")
        return 0
    try:
        return wait_slurm(todo, submitted, out, args.interval or 10.0)
    except KeyboardInterrupt:
        out.write("stopped waiting; the submitted jobs keep running (see --status)\n")
        return 130


def _exit_code(statuses: dict[int, Status]) -> int:
    return 0 if all(s.state == "done" for s in statuses.values()) else 1


def _rebuild_flags(args: argparse.Namespace) -> str:
    flags = [f"--size {args.size}"] if args.size else []
    flags += [f"--root {shlex.quote(str(args.root))}"]
    flags += [f"--seeds {args.seeds}"] if args.seeds else []
    flags += [f"--steps {args.steps}"] if args.steps else []
    flags += [f"--definitions {shlex.quote(str(args.definitions))}"] if \
        args.definitions != PAPER_DIR else []
    return " ".join(flags)

