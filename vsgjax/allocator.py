"""Host memory allocator for XLA:CPU: mimalloc, giving freed memory back after 100 ms.

XLA:CPU allocates every call's scratch space with ``malloc`` and frees it when the call returns;
with glibc, blocks that large are unmapped on ``free`` and page-faulted back in by the next
update. mimalloc with :data:`MIMALLOC_OPTIONS` reuses them (docs/benchmarks.md has the numbers).
It must be loaded when the process starts (``LD_PRELOAD``): the Makefile does it for every
target; by hand, ``env $(python vsgjax/allocator.py) python ...``. Running this file prints
the variable assignments (nothing where the library is not installed).
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
        return ("host allocator: mimalloc, reusing freed memory for 100 ms "
                "(vsgjax/allocator.py)")
    return ("host allocator: the C library's (CPU updates run 1.5-2x faster with mimalloc: "
            "start with `env $(python vsgjax/allocator.py) ...`; make does)")


if __name__ == "__main__":
    print(" ".join(f"{k}={v}" for k, v in allocator_env().items()))
