"""The local backend: the jobs as subprocesses of the launcher, a few processes at a time (a
process may train several seeds), with a live status table; SIGINT / SIGTERM stop them (they
save a checkpoint), a second signal kills them."""

from __future__ import annotations

import math
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field

from experiments.launch.jobs import Job, Process, group_processes, next_to_start
from experiments.launch.process import (
    STOP_TIMEOUT_S,
    job_env,
    open_log,
    reap,
    send_signal,
    start_process,
    write_done,
)
from experiments.launch.status import checkpoint_step, format_table, job_status


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
    """Runs jobs as subprocesses and shows their status: ``parallel`` processes at a time or,
    with ``spread``, as many as fill ``parallel * seeds_per_process`` host devices.

    Training jobs of one task, method and config go ``seeds_per_process`` to a process (spread
    over forced host devices with ``spread``; see :func:`group_processes`); a lone seed (the
    third of three, two to a process) then starts beside another one (:func:`next_to_start`)."""

    jobs: list[Job]
    parallel: int = 1
    interval: float | None = None  # seconds between tables (default: 5 on a TTY, 60 otherwise)
    out: object = sys.stdout
    poll_s: float = 0.5
    seeds_per_process: int = 1
    spread: bool = False
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

    def _queue(self) -> list[Process]:
        """The processes to start: launchable jobs, grouped; the others' states and notes."""
        statuses = {job.index: job_status(job) for job in self.jobs}
        for job in self.jobs:
            status = statuses[job.index]
            self.states[job.index] = "queued" if status.launchable else status.state
            if status.state == "done":
                self.notes[job.index] = "skipped: finished before this launch"
        launchable = [job for job in self.jobs if statuses[job.index].launchable]
        return group_processes(launchable, self.seeds_per_process, self.spread,
                               lambda job: checkpoint_step(job.job_dir))

    def _next(self, queue: list[Process], running: dict) -> int | None:
        """The index in ``queue`` of the process to start now, or None."""
        capacity = self.parallel * (self.seeds_per_process if self.spread else 1)
        used = sum(process.devices for process, _, _ in running.values())
        return next_to_start(queue, capacity - used, idle=not running)

    def _start(self, process: Process, env: dict[str, str]) -> tuple[subprocess.Popen, object]:
        command = process.command()
        log = open_log(process.leader.job_dir, command, "launch (local)")
        for job in process.jobs[1:]:
            open_log(job.job_dir, command, f"launch (local; output in {process.leader.log})"
                     ).close()
        return start_process(command, log, process.env(env)), log

    def run(self) -> int:
        tty = bool(getattr(self.out, "isatty", lambda: False)())
        interval = self.interval if self.interval is not None else (5.0 if tty else 60.0)
        queue = self._queue()
        running: dict[int, tuple[Process, subprocess.Popen, object]] = {}
        progress: dict[int, _Progress] = {}  # of every job of a running process
        env = job_env(self.parallel)
        previous = {sig: signal.signal(sig, self._handle) for sig in (signal.SIGINT,
                                                                      signal.SIGTERM)}
        shown_lines, last_table, forwarded, killed = 0, -math.inf, False, False
        try:
            while True:
                if self._stop is not None and not forwarded:
                    forwarded = True
                    name = signal.Signals(self._stop).name
                    self._print(f"{name}: stopping {len(running)} running process(es) "
                                "(SIGTERM: they save a checkpoint); a second signal kills them")
                    for _, child, _ in running.values():
                        send_signal(child, signal.SIGTERM)
                if self._kill and not killed:
                    killed = True
                    for _, child, _ in running.values():
                        send_signal(child, signal.SIGKILL)
                while self._stop is None and (index := self._next(queue, running)) is not None:
                    process = queue.pop(index)
                    child, log = self._start(process, env)
                    running[process.leader.index] = (process, child, log)
                    for job in process.jobs:
                        self.states[job.index] = "running"
                        progress[job.index] = _Progress(time.monotonic())
                    if not tty:
                        self._print(f"{_clock()} started {process.leader.index} {process.name}:"
                                    f" {process.leader.log}")
                for index, (process, child, log) in list(running.items()):
                    code = child.poll()
                    if code is None:
                        continue
                    log.close()
                    del running[index]
                    for job in process.jobs:
                        del progress[job.index]
                        state, note = finished_after_exit(job, code)
                        self.states[job.index], self.notes[job.index] = state, note
                        if not tty:
                            self._print(f"{_clock()} {state} {job.index} {job.name}"
                                        + (f": {note}" if note else ""))
                now = time.monotonic()
                finished = not running and (self._stop is not None or not queue)
                if finished or now - last_table >= interval:
                    last_table = now
                    table = self._table(progress, now, tty)
                    if tty and shown_lines:
                        self.out.write(f"\x1b[{shown_lines}F\x1b[J")
                    self._print(table)
                    shown_lines = table.count("\n") + 1
                if finished:
                    break
                time.sleep(self.poll_s)
        finally:
            for _, child, log in running.values():  # only after an error in the loop
                send_signal(child, signal.SIGTERM)
                reap(child, STOP_TIMEOUT_S)
                log.close()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        if self._stop is not None:
            return 128 + self._stop
        return 0 if all(state == "done" for state in self.states.values()) else 1

    def _table(self, running: dict[int, _Progress], now: float, tty: bool) -> str:
        """The status table; ``running``: the progress of every job of a running process."""
        statuses, etas = {}, {}
        for job in self.jobs:
            status = job_status(job)
            if self.notes.get(job.index):
                status.note = self.notes[job.index]
            elif job.index in running:
                status.note = ""  # not "resumes from ...": it is resuming
            statuses[job.index] = status
            if job.index in running and job.kind == "train":
                progress = running[job.index]
                progress.observe(status.step, now)
                if progress.rate and status.total is not None:
                    etas[job.index] = max(0, status.total - status.step) / progress.rate
        limit = max(5, shutil.get_terminal_size().lines - 4) if tty else None
        return format_table(self.jobs, statuses, self.states, etas, limit)
