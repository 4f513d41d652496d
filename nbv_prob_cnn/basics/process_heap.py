"""Keep a long-running process's heap from holding on to memory it has freed (glibc).

A node allocates and frees multi-megabyte arrays on every request (grids, ray buffers, the CNN's
activations). With glibc's defaults, the threshold above which ``malloc`` maps a block on its own
(and ``free`` returns it to the system) slides up after the first large free, up to 32 MiB; from
then on such arrays are carved from the heaps of the executor's threads, and the holes they leave
stay resident. In an 8-minute soak of the simulated graph this made ``gain_server`` grow 25 % and
``nbv_planner`` 22 % after the first exploration (studies/results/soak/README.md).

What is done about it, measured side by side in 8-minute soaks and on the CNN and the gain
search of a 3DT grid (docs/ros.md#memory-of-long-running-nodes):

- every ``HEAP_TRIM_PERIOD_S`` the node calls ``malloc_trim(0)``, which hands the free pages of
  every arena back to the system (:func:`release_free_heap`);
- at most ``ARENAS`` arenas (glibc's default: 8 per core).

Fixing the mapping threshold at 1 MiB instead bounds the growth as well, but every multi-megabyte
block is then mapped and faulted in afresh: the in-process plan took 1.22 s instead of 1.00 s.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from collections.abc import Mapping

#: ``mallopt`` parameter (glibc's ``malloc.h``).
M_ARENA_MAX = -8
#: Arenas at most; Python threads take turns on the GIL anyway.
ARENAS = 2
#: Seconds between two :func:`release_free_heap` calls of a node.
HEAP_TRIM_PERIOD_S = 1.0
#: Set to ``0`` to leave glibc's defaults and never trim (e.g. to compare).
ENV_SWITCH = "NBV_HEAP_TUNING"


def _libc():
    """The C library with ``mallopt`` and ``malloc_trim`` typed; None when it is not glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None
    if not (hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim")):
        return None
    libc.mallopt.argtypes, libc.mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    libc.malloc_trim.argtypes, libc.malloc_trim.restype = [ctypes.c_size_t], ctypes.c_int
    return libc


_LIBC = _libc()


def heap_tuning_enabled(environ: Mapping[str, str] | None = None) -> bool:
    """False when ``NBV_HEAP_TUNING=0`` or the C library is not glibc (no ``malloc_trim``)."""
    env = os.environ if environ is None else environ
    return env.get(ENV_SWITCH, "1") != "0" and _LIBC is not None


def limit_heap_retention(arenas: int = ARENAS, environ: Mapping[str, str] | None = None) -> str:
    """Bound the number of arenas with ``mallopt`` and say what the process will do.

    Call it early in a process's ``main`` (before it starts its own threads); the process then
    calls :func:`release_free_heap` every :data:`HEAP_TRIM_PERIOD_S`. ``MALLOC_ARENA_MAX``, when
    set, is left as the user set it.

    Returns:
        A line for the log: the settings applied, or why none were (not glibc, switched off).
    """
    env = os.environ if environ is None else environ
    if env.get(ENV_SWITCH, "1") == "0":
        return f"heap: glibc defaults, no trimming ({ENV_SWITCH}=0)"
    if not heap_tuning_enabled(env):
        return "heap: not glibc, defaults kept"
    if "MALLOC_ARENA_MAX" in env:
        arena_line = f"malloc_arena_max={env['MALLOC_ARENA_MAX']} from the environment"
    else:
        arena_line = f"malloc_arena_max={arenas}" if _LIBC.mallopt(M_ARENA_MAX, arenas) == 1 else "arenas: refused"
    return f"heap: {arena_line}, freed pages returned every {HEAP_TRIM_PERIOD_S:g} s (malloc_trim)"


def release_free_heap() -> bool:
    """``malloc_trim(0)``: return the free pages of every arena to the system.

    Returns:
        True when some memory was released.
    """
    return _LIBC is not None and bool(_LIBC.malloc_trim(0))
