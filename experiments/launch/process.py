"""A job's process, for every backend that runs one: its environment, its log, starting,
signalling and reaping it."""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from experiments.launch.jobs import LOG_FILE, REPO
from vsgjax.allocator import allocator_env
from vsgjax.data import checkpoint

STOP_TIMEOUT_S = 600  # how long a stopped job may take to save its checkpoint


def job_env(parallel: int = 1) -> dict[str, str]:
    """The environment of a job's process: the launcher's, unbuffered output, the host
    allocator of :mod:`vsgjax.allocator` and, with several jobs per machine, a share of the GPU."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    if "LD_PRELOAD" not in env:
        env.update(allocator_env())
    if parallel > 1 and not {"XLA_PYTHON_CLIENT_MEM_FRACTION",
                             "XLA_PYTHON_CLIENT_PREALLOCATE"} & set(env):
        env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{0.9 / parallel:.3f}"
    return env


def default_backend(env: dict[str, str]) -> str:
    """The JAX platform (``cpu``, ``gpu``, ``tpu``) a job started with ``env`` trains on, asked
    of a short-lived process so that the launcher itself holds no accelerator."""
    result = subprocess.run([sys.executable, "-c", "import jax; print(jax.default_backend())"],
                            cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    if result.returncode != 0:
        raise RuntimeError(f"could not start JAX to find the jobs' platform: "
                           f"{result.stderr.strip()[-2000:]}")
    return result.stdout.strip().splitlines()[-1]


def _now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S")


def open_log(job_dir: Path, command: Sequence[str], how: str):
    """``<job dir>/launch.log`` opened for appending, after a header line for this launch."""
    job_dir = Path(job_dir)
    job_dir.mkdir(parents=True, exist_ok=True)
    log = open(job_dir / LOG_FILE, "a")
    log.write(f"=== {_now()} {how}: {shlex.join(command)}\n")
    log.flush()
    return log


def write_done(marker: Path) -> None:
    """The finished marker of a rollouts job: the time it finished."""
    checkpoint.atomic_write(Path(marker), f"{_now()}\n".encode())


def start_process(command: Sequence[str], log, env: dict[str, str],
                  ignore_signals: Sequence[int] = ()) -> subprocess.Popen:
    """Start a job in its own session (a Ctrl-C at the terminal reaches only the launcher, which
    forwards one SIGTERM) with ``ignore_signals`` ignored (SLURM's submitit signal)."""
    def ignore():
        for signum in ignore_signals:
            signal.signal(signum, signal.SIG_IGN)

    return subprocess.Popen(list(command), cwd=REPO, env=env, stdout=log,
                            stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            start_new_session=True, preexec_fn=ignore if ignore_signals else None)


def send_signal(process: subprocess.Popen, signum: int) -> None:
    """``signum`` to ``process``, unless it has already exited."""
    try:
        process.send_signal(signum)
    except ProcessLookupError:
        pass


def reap(process: subprocess.Popen, timeout: float) -> bool:
    """Wait for ``process`` to exit with ``os.waitpid``: Popen.wait/poll from a signal handler
    can spin on the lock the interrupted poll() holds. False if it still runs at ``timeout``."""
    deadline = time.monotonic() + timeout
    while process.returncode is None:
        try:
            pid, status = os.waitpid(process.pid, os.WNOHANG)
        except ChildProcessError:  # reaped by the interrupted poll()
            return True
        if pid:
            process.returncode = os.waitstatus_to_exitcode(status)
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.2)
    return True
