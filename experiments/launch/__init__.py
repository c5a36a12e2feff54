"""Launch an experiment's runs (``python -m experiments.launch NAME``).

The experiment expands into jobs, one or several seeds to a process (``jobs``); their files
say what is done (``status``, with the table); the backends run them: ``local`` subprocesses,
a ``slurm`` job array through submitit, or a ``script`` to submit by hand (``--backend
print``); ``process`` is what the local and slurm backends share; ``cli`` is the command line.
The manual is docs/experiments.md.
"""

from experiments.launch.cli import BACKENDS, main, parse_args
from experiments.launch.jobs import (
    DONE_FILE,
    LOG_FILE,
    Job,
    LaunchError,
    Process,
    group_processes,
    make_jobs,
    next_to_start,
)
from experiments.launch.local import LocalRunner
from experiments.launch.script import COMMANDS_FILE, SBATCH_FILE, write_print
from experiments.launch.slurm import SUBMITIT_DIR, SlurmJob, submit_slurm, wait_slurm
from experiments.launch.status import (
    Status,
    checkpoint_step,
    format_table,
    job_status,
    train_status,
)

__all__ = [
    "BACKENDS", "COMMANDS_FILE", "DONE_FILE", "LOG_FILE", "SBATCH_FILE", "SUBMITIT_DIR", "Job",
    "LaunchError", "LocalRunner", "Process", "SlurmJob", "Status", "checkpoint_step",
    "format_table", "group_processes", "job_status", "main", "make_jobs", "next_to_start",
    "parse_args", "submit_slurm", "train_status", "wait_slurm", "write_print",
]
