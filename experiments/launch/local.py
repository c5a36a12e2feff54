"""The local backend: the jobs as subprocesses of the launcher, a few at a time, with a live
status table; SIGINT / SIGTERM stop them (they save a checkpoint), a second signal kills them."""

from __future__ import annotations

import math
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field

from experiments.launch.jobs import Job
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


def finished_after_exit(job: Job, code: int) -> tuple[str, str]:
    """(state, note) of a job whose process exited with ``code``."""
    if code == 0 and job.done_marker is not None:
        write_done(job.done_marker)
    status = job_status(job)
    if status.state == "done":  # also a run stopped after its last checkpoint
        return "done", ""
    if code == 0:
        return "failed", f"exited 0 but is {status.state}; see {job.log}"
    if code in (128 + signal.SIGTERM, -signal.SIGTERM, 128 + signal.SIGINT, -signal.SIGINT):
        return "stopped", "resumable: relaunch to continue"
    return "failed", f"exit code {code}; see {job.log}"


def _clock() -> str:
    return time.strftime("%H:%M:%S")


@dataclass
class _Progress:
    """Env-step rate of a running training job, from the launcher's observations."""

    started: float
    first_step: int | None = None
    first_time: float = 0.0
    rate: float | None = None

    def observe(self, step: int | None, now: float) -> None:
        if step is None:
            return
        if self.first_step is None:
            self.first_step, self.first_time = step, now
        elif step > self.first_step and now > self.first_time:
            self.rate = (step - self.first_step) / (now - self.first_time)


@dataclass
class LocalRunner:
    """Runs jobs as subprocesses, ``parallel`` at a time, and shows their status."""

    jobs: list[Job]
    parallel: int = 1
    interval: float | None = None  # seconds between tables (default: 5 on a TTY, 60 otherwise)
    out: object = sys.stdout
    poll_s: float = 0.5
    states: dict[int, str] = field(default_factory=dict)
    notes: dict[int, str] = field(default_factory=dict)
    _stop: int | None = None
    _kill: bool = False

    def _handle(self, signum, frame) -> None:
        if self._stop is not None:
            self._kill = True
        self._stop = signum

    def _print(self, text: str) -> None:
        self.out.write(text + "\n")
        self.out.flush()

    def run(self) -> int:
        tty = bool(getattr(self.out, "isatty", lambda: False)())
        interval = self.interval if self.interval is not None else (5.0 if tty else 60.0)
        statuses = {job.index: job_status(job) for job in self.jobs}
        queue = [job for job in self.jobs if statuses[job.index].launchable]
        for job in self.jobs:
            status = statuses[job.index]
            self.states[job.index] = "queued" if status.launchable else status.state
            if status.state == "done":
                self.notes[job.index] = "skipped: finished before this launch"
        running: dict[int, tuple[Job, subprocess.Popen, object, _Progress]] = {}
        env = job_env(self.parallel)
        previous = {sig: signal.signal(sig, self._handle) for sig in (signal.SIGINT,
                                                                      signal.SIGTERM)}
        shown_lines, last_table, forwarded, killed = 0, -math.inf, False, False
        try:
            while True:
                if self._stop is not None and not forwarded:
                    forwarded = True
                    name = signal.Signals(self._stop).name
                    self._print(f"{name}: stopping {len(running)} running job(s) (SIGTERM: they "
                                "save a checkpoint); a second signal kills them")
                    for _, process, _, _ in running.values():
                        send_signal(process, signal.SIGTERM)
                if self._kill and not killed:
                    killed = True
                    for _, process, _, _ in running.values():
                        send_signal(process, signal.SIGKILL)
                while self._stop is None and queue and len(running) < self.parallel:
                    job = queue.pop(0)
                    command = job.command()
                    log = open_log(job.job_dir, command, "launch (local)")
                    running[job.index] = (job, start_process(command, log, env), log,
                                          _Progress(time.monotonic()))
                    self.states[job.index] = "running"
                    if not tty:
                        self._print(f"{_clock()} started {job.index} {job.name}: {job.log}")
                for index, (job, process, log, _) in list(running.items()):
                    code = process.poll()
                    if code is None:
                        continue
                    log.close()
                    del running[index]
                    state, note = finished_after_exit(job, code)
                    self.states[index], self.notes[index] = state, note
                    if not tty:
                        self._print(f"{_clock()} {state} {index} {job.name}"
                                    + (f": {note}" if note else ""))
                now = time.monotonic()
                finished = not running and (self._stop is not None or not queue)
                if finished or now - last_table >= interval:
                    last_table = now
                    table = self._table(running, now, tty)
                    if tty and shown_lines:
                        self.out.write(f"\x1b[{shown_lines}F\x1b[J")
                    self._print(table)
                    shown_lines = table.count("\n") + 1
                if finished:
                    break
                time.sleep(self.poll_s)
        finally:
            for _, process, log, _ in running.values():  # only after an error in the loop
                send_signal(process, signal.SIGTERM)
                reap(process, STOP_TIMEOUT_S)
                log.close()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        if self._stop is not None:
            return 128 + self._stop
        return 0 if all(state == "done" for state in self.states.values()) else 1

    def _table(self, running: dict, now: float, tty: bool) -> str:
        statuses, etas = {}, {}
        for job in self.jobs:
            status = job_status(job)
            if self.notes.get(job.index):
                status.note = self.notes[job.index]
            elif job.index in running:
                status.note = ""  # not "resumes from ...": it is resuming
            statuses[job.index] = status
            if job.index in running and job.kind == "train":
                progress = running[job.index][3]
                progress.observe(status.step, now)
                if progress.rate and status.total is not None:
                    etas[job.index] = max(0, status.total - status.step) / progress.rate
        limit = max(5, shutil.get_terminal_size().lines - 4) if tty else None
        return format_table(self.jobs, statuses, self.states, etas, limit)

