"""The slurm backend: the jobs as one SLURM job array through submitit, each task requeued on
a timeout or preemption (the command saves a checkpoint first and resumes from it)."""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path

from experiments.launch.jobs import LOG_FILE, Job, LaunchError
from experiments.launch.process import (
    STOP_TIMEOUT_S,
    job_env,
    open_log,
    reap,
    send_signal,
    start_process,
    write_done,
)
from experiments.launch.status import format_table, job_status
from experiments.spec import Experiment

try:  # the slurm backend's requeueable job needs submitit (the "slurm" extra)
    from submitit.helpers import Checkpointable as _Checkpointable
except ImportError:  # pragma: no cover - depends on the environment
    _Checkpointable = object

SUBMITIT_DIR = ".submitit"
INSTALL_SLURM = 'the slurm backend needs submitit: pip install -e ".[slurm]"'


def has_submitit() -> bool:
    return _Checkpointable is not object


class SlurmJob(_Checkpointable):
    """The callable a SLURM array task runs: one job's command as a subprocess.

    On a timeout or preemption signal submitit calls :meth:`checkpoint`, which stops the
    command with SIGTERM (the trainer saves a checkpoint) and returns a requeue of this same
    callable; the requeued task reruns the command, which resumes from that checkpoint.
    """

    def __init__(self, command: Sequence[str], job_dir: str, done_marker: str | None = None,
                 env: dict[str, str] | None = None):
        self.command, self.job_dir, self.done_marker = list(command), str(job_dir), done_marker
        self.env = env or {}
        self._process: subprocess.Popen | None = None

    def __call__(self) -> int:
        log_dir = Path(self.job_dir)
        env = job_env()
        env.update(self.env)
        how = f"launch (slurm {os.environ.get('SLURM_JOB_ID', 'local')})"
        with open_log(log_dir, self.command, how) as log:
            usr = [getattr(signal, "SIG" + os.environ.get("SUBMITIT_PREEMPT_SIGNAL", "USR2"),
                           signal.SIGUSR2)]
            self._process = start_process(self.command, log, env, ignore_signals=usr)
            while (code := self._process.poll()) is None:  # not wait(): see checkpoint()
                time.sleep(1.0)
        self._process = None
        if code in (128 + signal.SIGTERM, -signal.SIGTERM):
            raise RuntimeError(f"the job was sent SIGTERM (preempted or cancelled) and saved a "
                               f"checkpoint; a requeue or relaunch resumes it ({log_dir})")
        if code != 0:
            raise RuntimeError(f"{shlex.join(self.command)} exited with {code}; see "
                               f"{log_dir / LOG_FILE} (relaunch to resume)")
        if self.done_marker:
            write_done(Path(self.done_marker))
        return code

    def checkpoint(self, *args, **kwargs):
        """Stop the command (it checkpoints) and requeue this job."""
        import submitit

        process = self._process
        if process is not None and process.returncode is None:
            send_signal(process, signal.SIGTERM)
            if not reap(process, STOP_TIMEOUT_S):
                send_signal(process, signal.SIGKILL)
                reap(process, 10)
        self._process = None
        return submitit.helpers.DelayedSubmission(self, *args, **kwargs)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_process"] = None  # a process does not travel with the pickled requeue
        return state


def submit_slurm(jobs: Sequence[Job], experiment: Experiment, root: Path,
                 args: argparse.Namespace) -> list:
    """Submit ``jobs`` as one array through ``submitit.AutoExecutor``; returns submitit jobs."""
    try:
        import submitit
    except ImportError:
        raise LaunchError(INSTALL_SLURM) from None
    folder = Path(root) / experiment.name / SUBMITIT_DIR
    common = dict(name=f"vsgjax-{experiment.name}", timeout_min=args.time,
                  gpus_per_node=args.gpus_per_job, cpus_per_task=args.cpus_per_job,
                  mem_gb=args.mem)
    if args.cluster == "local":  # submitit's local executor: this machine, same requeue path
        executor = submitit.LocalExecutor(folder=folder, max_num_timeout=args.max_requeues)
        parameters = dict(common, signal_delay_s=args.signal_delay)
    else:
        try:
            executor = submitit.AutoExecutor(folder=folder, cluster="slurm",
                                             slurm_max_num_timeout=args.max_requeues)
        except RuntimeError as error:  # no srun / sbatch on this machine
            raise LaunchError(f"{error}; submit from the cluster's login node, or write an "
                              "sbatch script with --backend print") from None
        parameters = dict(common, slurm_partition=args.partition,
                          slurm_array_parallelism=args.jobs,
                          slurm_signal_delay_s=args.signal_delay)
    executor.update_parameters(**{k: v for k, v in parameters.items() if v is not None})
    return executor.submit_array([
        SlurmJob(job.command(), str(job.job_dir),
                 str(job.done_marker) if job.done_marker else None) for job in jobs])


def wait_slurm(jobs: Sequence[Job], submitted: Sequence, out, interval: float) -> int:
    """Show the table until every submitted job ended; 0 when all of them succeeded."""
    states = {job.index: "submitted" for job in jobs}
    by_index = dict(zip([job.index for job in jobs], submitted, strict=True))
    failed = False
    while True:
        for index, handle in by_index.items():
            if states[index] in ("done", "failed"):
                continue
            if handle.done():
                try:
                    handle.result()
                    states[index] = "done"
                except Exception as error:  # the job's failure, reported in the table
                    states[index], failed = "failed", True
                    out.write(f"job {index} failed: {str(error).splitlines()[-1][:300]}\n")
            else:
                states[index] = handle.state.lower()
        ended = all(state in ("done", "failed") for state in states.values())
        statuses = {job.index: job_status(job) for job in jobs}
        for index, state in states.items():
            if state not in ("done", "failed"):
                statuses[index].note = ""
        out.write(format_table(jobs, statuses, states) + "\n")
        out.flush()
        if ended:
            return 1 if failed else 0
        time.sleep(interval)

