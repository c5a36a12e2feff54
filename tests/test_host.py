"""Host allocator: mimalloc is installed, preloads, keeps its options, and the Makefile uses it."""

import subprocess
import sys
from pathlib import Path

from vsgjax import host

ROOT = Path(__file__).resolve().parents[1]
REPORT = "from vsgjax import host; import numpy; numpy.ones(1 << 26).sum(); " \
         "print(host.allocator_active()); print(host.allocator_line())"


def _child(env: dict[str, str]) -> list[str]:
    out = subprocess.run([sys.executable, "-c", REPORT], env=env, cwd=ROOT, capture_output=True,
                         text=True, check=True)
    assert "mimalloc: warning" not in out.stderr and "error" not in out.stderr.lower(), out.stderr
    return out.stdout.splitlines()


def test_mimalloc_is_installed_and_its_env_names_it():
    env = host.allocator_env()
    assert host.mimalloc_library() is not None, "cmeel-mimalloc (a dependency) is not installed"
    assert env["LD_PRELOAD"] == str(host.mimalloc_library())
    assert {k: env[k] for k in host.MIMALLOC_OPTIONS} == host.MIMALLOC_OPTIONS


def test_a_process_started_with_the_env_runs_on_mimalloc():
    base = {"PATH": "/usr/bin:/bin"}
    active, line = _child(dict(base, **host.allocator_env()))
    assert active == "True" and "mimalloc" in line
    active, line = _child(host.glibc_env(dict(base, **host.allocator_env())))
    assert active == "False" and "python vsgjax/host.py" in line


def test_the_makefile_starts_python_with_the_allocator():
    printed = subprocess.run([sys.executable, "vsgjax/host.py"], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout.split()
    assert printed == [f"{k}={v}" for k, v in host.allocator_env().items()]
    makefile = (ROOT / "Makefile").read_text()
    assert "$(shell $(BIN)/python vsgjax/host.py) $(BIN)/python" in makefile
    assert makefile.count("$(RUN) -m") >= 4  # test, test-fast, bench, train, evaluate
