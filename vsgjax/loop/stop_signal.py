"""Ctrl-C and SIGTERM for a training loop: answered at once, acted on between steps.

A Python signal handler runs only when the main thread is back in the interpreter, and a
training step can keep it inside XLA for minutes (a first compile, an evaluation). So the
answer does not wait for the handler: :func:`signal.set_wakeup_fd` makes the C-level handler
write the signal's number to a pipe, and a watcher thread reading that pipe says at once what
happens next. The loop itself polls :attr:`StopSignal.requested` between steps, then saves a
checkpoint and exits.

A second signal exits at once: the Python handler raises ``KeyboardInterrupt`` when the main
thread is in the interpreter; when it is not back within :data:`FORCE_EXIT_AFTER_S`, the
watcher ends the process with ``os._exit`` (as a kill would: checkpoints are written
atomically, so the newest complete one is kept).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterable
from typing import Any

FORCE_EXIT_AFTER_S = 1.0


def first_signal_message(signum: int) -> str:
    return (f"\n{signal.Signals(signum).name} received: the current step finishes (a first "
            "compile or an evaluation can take minutes), then a checkpoint is saved and the run "
            "exits. Press Ctrl-C again to exit at once, keeping the newest saved checkpoint.\n")


def second_signal_message(signum: int) -> str:
    return (f"\nsecond {signal.Signals(signum).name}: exiting now; the newest saved checkpoint "
            "is kept, rerun the same command to resume from it\n")


class StopSignal:
    """A flag set by SIGINT/SIGTERM so a training loop can save a checkpoint and exit cleanly.

    Use as a context manager (handlers are installed on enter, the previous ones restored on
    exit); the loop polls :attr:`requested`. Must be entered from the main thread.
    """

    def __init__(self, signals: Iterable[int] = (signal.SIGINT, signal.SIGTERM),
                 stream: Any = None):
        self.signals = tuple(signals)
        self.requested = False
        self.received: int | None = None
        self._stream = stream
        self._previous: dict[int, Any] = {}
        self._previous_wakeup_fd = -1
        self._pipe: tuple[int, int] | None = None
        self._closed = threading.Event()
        self._watcher: threading.Thread | None = None

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt(f"second signal {signal.Signals(signum).name}")
        self.requested = True
        self.received = signum

    def _say(self, text: str) -> None:
        stream = self._stream or sys.stderr
        stream.write(text)
        stream.flush()

    def _watch(self, read_fd: int) -> None:
        """Answer each of our signals as it arrives, whatever the main thread is doing."""
        seen = 0
        while not self._closed.is_set():
            try:
                data = os.read(read_fd, 64)
            except OSError:
                return
            if not data:
                return
            for signum in data:
                if signum not in self.signals:
                    continue
                seen += 1
                if seen == 1:
                    self._say(first_signal_message(signum))
                elif not self._closed.wait(FORCE_EXIT_AFTER_S):
                    self._say(second_signal_message(signum))
                    os._exit(128 + signum)

    def __enter__(self) -> StopSignal:
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("StopSignal must be entered from the main thread")
        for signum in self.signals:
            self._previous[signum] = signal.signal(signum, self._handle)
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        self._pipe = (read_fd, write_fd)
        self._previous_wakeup_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        self._closed.clear()
        self._watcher = threading.Thread(target=self._watch, args=(read_fd,),
                                         name="stop-signal", daemon=True)
        self._watcher.start()
        return self

    def __exit__(self, *exc_info: Any) -> None:
        signal.set_wakeup_fd(self._previous_wakeup_fd)
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()
        self._closed.set()
        read_fd, write_fd = self._pipe
        os.close(write_fd)  # the watcher's read returns b"" and it ends
        self._watcher.join(timeout=5)
        os.close(read_fd)
        self._pipe = self._watcher = None
