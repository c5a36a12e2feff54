"""Host allocator: mimalloc is installed, preloads, keeps its options, and the Makefile uses it."""

import subprocess
import sys
from pathlib import Path

from vsgjax import allocator

ROOT = Path(__file__).resolve().parents[2]
REPORT = "from vsgjax import allocator; import numpy; numpy.ones(1 << 26).sum(); " \
         "print(allocator.allocator_active()); print(allocator.allocator_line())"


def _child(env: dict[str, str]) -> list[str]:
    out = subprocess.run([sys.executable, "-c", REPORT], env=env, cwd=ROOT, capture_output=True,
                         text=True, check=True)
    assert "mimalloc: warning" not in out.stderr and "error" not in out.stderr.lower(), out.stderr
    return out.stdout.splitlines()


def test_mimalloc_is_installed_and_its_env_names_it():
    env = allocator.allocator_env()
    assert allocator.mimalloc_library() is not None, "cmeel-mimalloc (a dependency) is missing"
    assert env["LD_PRELOAD"] == str(allocator.mimalloc_library())
    assert {k: env[k] for k in allocator.MIMALLOC_OPTIONS} == allocator.MIMALLOC_OPTIONS


def test_a_process_started_with_the_env_runs_on_mimalloc():
    base = {"PATH": "/usr/bin:/bin"}
    active, line = _child(dict(base, **allocator.allocator_env()))
    assert active == "True" and "mimalloc" in line
    active, line = _child(allocator.glibc_env(dict(base, **allocator.allocator_env())))
    assert active == "False" and "python vsgjax/allocator.py" in line


def test_the_makefile_starts_python_with_the_allocator():
    printed = subprocess.run([sys.executable, "vsgjax/allocator.py"], cwd=ROOT,
                             capture_output=True,
                             text=True, check=True).stdout.split()
    assert printed == [f"{k}={v}" for k, v in allocator.allocator_env().items()]
    makefile = (ROOT / "Makefile").read_text()
    assert "$(shell $(BIN)/python vsgjax/allocator.py) $(BIN)/python" in makefile
    assert makefile.count("$(RUN) -m") >= 4  # test, test-fast, bench, train, evaluate
