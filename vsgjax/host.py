"""Host memory allocator for fast XLA:CPU updates: mimalloc, reusing freed memory for 100 ms.

XLA:CPU allocates the scratch space of every call with ``malloc`` (1.9 GiB for one ``small``
world-model update, 5.3 GiB at ``paper`` size) and frees it when the call returns. glibc serves
blocks that large with ``mmap`` and unmaps them on ``free``, so every update page-faults its
whole scratch space back in and the kernel zero-fills it: measured 0.5 million faults and ~1 s
of kernel time per ``small`` update, 1.4 million and ~5 s per ``paper`` update on a 2-core VM
(glibc's own tunables removed the faults only in some runs). mimalloc (the ``cmeel-mimalloc``
wheel) with :data:`MIMALLOC_OPTIONS` serves even the largest blocks from its arenas and gives
freed memory back to the OS only after it stayed unused for 100 ms: the scratch space that
XLA frees and reallocates within an update is reused without faults, and what a peak left
behind is returned. Measured on the full agent update (``bench_memory``, ``BENCHMARKS.md``):
``paper`` 5.9 s and 7.9 GiB peak against glibc's 8.9 s and 8.3 GiB. Keeping every freed byte
(``MIMALLOC_PURGE_DELAY=-1``, the setting of earlier sessions) was 5% faster, but nothing it
freed ever went back: this update on it was once OOM-killed at 24.3 GiB on a 24 GiB machine
(in the benchmark's 4-update process it peaked at 8.6 GiB; the growth was not reproduced).

The allocator must be loaded when the process starts (``LD_PRELOAD``). The Makefile does it for
every target; by hand: ``env $(python vsgjax/host.py) python ...``. Running this file prints the
variable assignments (nothing where the library is not installed).
"""

from __future__ import annotations

import os
import sysconfig
from pathlib import Path

MIMALLOC_OPTIONS = {
    "MIMALLOC_PURGE_DELAY": "100",  # ms unused before freed memory goes back to the OS
    "MIMALLOC_ARENA_RESERVE": "16GiB",  # address space per arena (reserved, not committed)
    "MIMALLOC_ARENA_MAX_OBJECT_SIZE": "64GiB",  # even XLA's largest buffers come from arenas
}


def mimalloc_library() -> Path | None:
    """Path of the ``libmimalloc.so`` the ``cmeel-mimalloc`` wheel installed, if any."""
    path = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "lib" / "libmimalloc.so"
    return path if path.exists() else None


def allocator_env() -> dict[str, str]:
    """Environment variables that start a process with mimalloc ({} if it is not installed)."""
    library = mimalloc_library()
    return {} if library is None else {"LD_PRELOAD": str(library), **MIMALLOC_OPTIONS}


def glibc_env(environ: dict[str, str]) -> dict[str, str]:
    """``environ`` without the allocator variables: a process started with it uses glibc."""
    return {k: v for k, v in environ.items() if k != "LD_PRELOAD" and k not in MIMALLOC_OPTIONS}


def allocator_active() -> bool:
    """Whether this process runs on mimalloc with :data:`MIMALLOC_OPTIONS`."""
    try:
        mapped = "libmimalloc" in Path("/proc/self/maps").read_text()
    except OSError:
        return False
    return mapped and all(os.environ.get(k) == v for k, v in MIMALLOC_OPTIONS.items())


def allocator_line() -> str:
    """One line for a run's header: which allocator this process uses."""
    if allocator_active():
        return "host allocator: mimalloc, reusing freed memory for 100 ms (vsgjax/host.py)"
    return ("host allocator: the C library's (CPU updates run 1.5-2x faster with mimalloc: "
            "start with `env $(python vsgjax/host.py) ...`; make does)")


if __name__ == "__main__":
    print(" ".join(f"{k}={v}" for k, v in allocator_env().items()))
