"""The print backend: ``commands.txt`` (one shell command per job) and ``sbatch.sh`` (a SLURM
array over its lines), for clusters without Python on the login node."""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Sequence
from pathlib import Path

from experiments.launch.jobs import LOG_FILE, REPO, Job
from experiments.spec import Experiment
from vsgjax.data import checkpoint

COMMANDS_FILE = "commands.txt"
SBATCH_FILE = "sbatch.sh"


def write_print(jobs: Sequence[Job], experiment: Experiment, root: Path,
                args: argparse.Namespace) -> tuple[Path, Path]:
    """``commands.txt`` (one shell command per job) and ``sbatch.sh`` (an array over its lines)."""
    directory = Path(root) / experiment.name
    directory.mkdir(parents=True, exist_ok=True)
    lines = []
    for job in jobs:
        line = shlex.join(job.command())
        if job.done_marker is not None:
            line += f" && touch {shlex.quote(str(job.done_marker))}"
        lines.append(line)
    commands = directory / COMMANDS_FILE
    checkpoint.atomic_write(commands, "".join(f"{line}\n" for line in lines).encode())
    (directory / ".sbatch").mkdir(exist_ok=True)
    options = [f"--job-name=vsgjax-{experiment.name}",
               f"--array=0-{len(jobs) - 1}" + (f"%{args.jobs}" if args.jobs else ""),
               f"--output={directory / '.sbatch'}/%A_%a.out", "--open-mode=append",
               f"--time={args.time}", f"--cpus-per-task={args.cpus_per_job}",
               "--signal=B:USR1@120", "--requeue"]
    if args.gpus_per_job:
        options.append(f"--gpus-per-node={args.gpus_per_job}")
    if args.mem:
        options.append(f"--mem={int(args.mem)}G")
    if args.partition:
        options.append(f"--partition={args.partition}")
    dirs = " ".join(shlex.quote(str(job.job_dir)) for job in jobs)
    script = "\n".join([
        "#!/bin/bash",
        f"# {experiment.name}: {len(jobs)} jobs, one per line of {commands}.",
        f"# Submit with: sbatch {directory / SBATCH_FILE}",
        "# Array task i runs line i+1, appending its output to <job dir>/launch.log. Two minutes",
        "# before the time limit it stops the command (SIGTERM: the trainer saves a checkpoint)",
        "# and requeues itself; the requeued task resumes from that checkpoint.",
        *(f"#SBATCH {option}" for option in options),
        "",
        f"cd {shlex.quote(str(REPO))}",
        f"DIRS=({dirs})",
        'DIR="${DIRS[$SLURM_ARRAY_TASK_ID]}"',
        f'LINE=$(sed -n "$((SLURM_ARRAY_TASK_ID + 1))p" {shlex.quote(str(commands))})',
        'mkdir -p "$DIR"',
        'echo "=== $(date "+%F %T") launch (sbatch ${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}):'
        f' $LINE" | tee -a "$DIR/{LOG_FILE}"',
        f'setsid bash -c "$LINE" >> "$DIR/{LOG_FILE}" 2>&1 &',
        "CHILD=$!",
        'trap \'echo "time limit near: stopping and requeueing"; kill -TERM -- -$CHILD; '
        'wait $CHILD; scontrol requeue "${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}"; '
        "exit 0' USR1",
        "wait $CHILD",
        "exit $?",
        "",
    ])
    sbatch = directory / SBATCH_FILE
    checkpoint.atomic_write(sbatch, script.encode())
    sbatch.chmod(0o755)
    return commands, sbatch
