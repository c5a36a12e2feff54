"""Ctrl-C and SIGTERM: the loop saves and exits between steps, the answer comes at once.

The "at once" cases run a subprocess whose main thread sits in one long C call (a key
derivation that never returns to the interpreter, as a compile does): the answer must be
printed before that call returns, and a second signal must end the process without it.
"""

import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from vsgjax.data import checkpoint
from vsgjax.loop.stop_signal import StopSignal

REPO_ROOT = Path(__file__).resolve().parents[2]


def run_script(body: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(body)], capture_output=True,
                          text=True, timeout=600, cwd=REPO_ROOT)


def test_stop_signal_lets_the_loop_save_and_exit(tmp_path):
    """SIGTERM then SIGINT sent to itself: each sets the flag, the loop saves and leaves."""
    result = run_script(f"""
        import os, signal
        import numpy as np
        from vsgjax.data import checkpoint
        from vsgjax.loop.stop_signal import StopSignal
        for save_step, signum in enumerate((signal.SIGTERM, signal.SIGINT)):
            with StopSignal() as stop:
                step = 0
                while not stop.requested:
                    step += 1
                    if step == 3:
                        os.kill(os.getpid(), signum)
                checkpoint.save({str(tmp_path)!r}, save_step, {{"step": np.array(step)}})
                print(signal.Signals(stop.received).name, step)
        print("handlers restored", signal.getsignal(signal.SIGTERM) == signal.SIG_DFL,
              signal.set_wakeup_fd(-1) == -1)
    """)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[:3] == ["SIGTERM 3", "SIGINT 3", "handlers restored True True"]
    assert [step for step, _ in checkpoint.list_checkpoints(tmp_path)] == [0, 1]
    assert result.stderr.count("a checkpoint is saved and the run exits") == 2


def test_second_signal_interrupts():
    with StopSignal([signal.SIGUSR1]) as stop:
        signal.raise_signal(signal.SIGUSR1)
        assert stop.requested and stop.received == signal.SIGUSR1
        with pytest.raises(KeyboardInterrupt, match="second signal SIGUSR1"):
            signal.raise_signal(signal.SIGUSR1)
    assert signal.getsignal(signal.SIGUSR1) == signal.SIG_DFL


# The main thread in one C call; a thread sends the signals once it has started.
LONG_C_CALL = """
    import hashlib, os, signal, sys, threading, time
    from vsgjax.loop.stop_signal import StopSignal

    def send(count):
        time.sleep(0.5)
        for _ in range(count):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)

    with StopSignal() as stop:
        threading.Thread(target=send, args=({count},), daemon=True).start()
        hashlib.pbkdf2_hmac("sha256", b"x", b"y", {iterations})
        print("long call returned", file=sys.stderr, flush=True)
    print("requested", stop.requested)
"""


def test_the_first_signal_is_answered_while_the_main_thread_is_in_c():
    result = run_script(LONG_C_CALL.format(count=1, iterations=20_000_000))
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "requested True"
    answer = result.stderr.index("SIGINT received: the current step finishes")
    assert answer < result.stderr.index("long call returned"), result.stderr


def test_a_second_signal_exits_at_once_even_inside_a_c_call():
    result = run_script(LONG_C_CALL.format(count=2, iterations=2**31 - 1))
    assert result.returncode == 128 + signal.SIGINT, result.stderr
    assert "second SIGINT: exiting now" in result.stderr
    assert "long call returned" not in result.stderr
    assert result.stdout == ""


def test_other_signals_and_the_restored_state():
    """A signal it does not watch is not answered, and leaving it restores the wakeup fd."""
    before = signal.set_wakeup_fd(-1)
    signal.set_wakeup_fd(before)
    with StopSignal([signal.SIGUSR1]) as stop:
        signal.raise_signal(signal.SIGUSR1)
    assert stop.requested
    assert signal.set_wakeup_fd(before) == before
    np.testing.assert_equal(stop.received, signal.SIGUSR1)
