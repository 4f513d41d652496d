"""A node's own Fast DDS files removed after it stops (issue 47).

Fast DDS (2.14.5) gives each participant a data segment (``fastrtps_<id>``) and a listening port
(``fastrtps_port<N>``), each with a lock file (``_el``) that only the owner holds, and the port with
a named mutex (``sem.fastrtps_port<N>_mutex``). Peers that sent to the participant map its port
too. When the node stops, its own close of the port is not the last one: the peers close theirs
0.5-3 s later, when they have processed the participant's departure, and the last of them removes
the file only if the port is still marked healthy. On this machine that failed in 5 of 6 SIGINT
exits of an idle ``nbv_planner``: the port file stayed with no process holding it.

So :func:`note_own_files` notes, before the node shuts down, the files the process created (those
with a lock file it holds), and :func:`release_after_exit` hands them to a detached process
(``python -m nbv_prob_cnn.ros.shm_release``) that waits until no process holds them any more, at
most :data:`RELEASE_WAIT_S`, and removes those that are left and held by none. A file still held
after that wait is left to its holder (a live process). The node's own exit is not delayed.

Imports no rclpy.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import ctypes.util
import os
import subprocess
import sys
import time
from collections.abc import Iterator

from nbv_prob_cnn.ros.graph import mapped_shm, segment_in_use

#: Longest wait of the detached process for the peers to close the node's files (they took up
#: to 3 s after an idle planner's SIGINT on a loaded 2-core machine).
RELEASE_WAIT_S = 15.0
#: How often it looks again.
POLL_S = 0.1
#: Lock-file suffix of a Fast DDS file held by its creator alone.
LOCK_SUFFIX = "_el"


def own_files(mapped: set[str]) -> set[str]:
    """Of the /dev/shm names a process maps or holds open (``mapped``), the Fast DDS files it
    created: each file whose lock file it holds, the lock file, and a port's named mutex."""
    own: set[str] = set()
    for name in mapped:
        if not name.startswith("fastrtps_") or not name.endswith(LOCK_SUFFIX):
            continue
        base = name[: -len(LOCK_SUFFIX)]
        own |= {name, base}
        if base.startswith("fastrtps_port"):
            own.add(f"sem.{base}_mutex")
    return own


def note_own_files() -> set[str]:
    """The Fast DDS files this process created (:func:`own_files` of its own mappings)."""
    return own_files(mapped_shm(os.getpid()))


def _held(name: str) -> bool:
    """Whether another live process holds ``name`` (a port's mutex: held with its port; this
    process maps the mutex while it holds it)."""
    me = frozenset({os.getpid()})
    if name.startswith("sem.") and name.endswith("_mutex"):
        return segment_in_use(name, me) or segment_in_use(name[len("sem.") : -len("_mutex")], me)
    return segment_in_use(name, me)


def _existing(names: set[str]) -> set[str]:
    return {name for name in names if os.path.exists(f"/dev/shm/{name}")}


@contextlib.contextmanager
def _port_mutex(port: str) -> Iterator[bool]:
    """Hold the named mutex of Fast DDS port file ``port`` (a POSIX semaphore, as Fast DDS takes it
    while it opens or creates the port): no participant opens the port while it is held. Yields
    False when the mutex exists and could not be taken within 1 s (someone opens the port now)."""
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    libc.sem_open.restype = ctypes.c_void_p
    libc.sem_open.argtypes = [ctypes.c_char_p, ctypes.c_int]
    for fn in (libc.sem_trywait, libc.sem_post, libc.sem_close):
        fn.argtypes = [ctypes.c_void_p]
    sem = libc.sem_open(f"/{port}_mutex".encode(), 0)
    if sem in (None, ctypes.c_void_p(-1).value):  # SEM_FAILED: no mutex, nobody opens the port
        yield True
        return
    taken = False
    try:
        deadline = time.monotonic() + 1.0
        while not (taken := libc.sem_trywait(sem) == 0) and time.monotonic() < deadline:
            time.sleep(0.01)
        yield taken
    finally:
        if taken:
            libc.sem_post(sem)
        libc.sem_close(sem)


def remove_unheld(names: set[str]) -> list[str]:
    """Remove those of ``names`` (Fast DDS files) that exist and that no live process holds; a
    port, its lock file and its mutex are judged and removed together, under the port's mutex.
    Returns the removed names."""
    ports = {name for name in names if name.startswith("fastrtps_port") and not name.endswith(LOCK_SUFFIX)}
    groups = [{p, p + LOCK_SUFFIX, f"sem.{p}_mutex"} & names for p in ports]
    grouped = set().union(*groups) if groups else set()
    groups += [{name} for name in names - grouped]
    removed: list[str] = []
    for group in groups:
        port = next((name for name in group if name in ports), None)
        with _port_mutex(port) if port else contextlib.nullcontext(True) as free:
            present = _existing(group)
            if not free or not present or any(_held(name) for name in present):
                continue
            for name in sorted(present):
                with contextlib.suppress(OSError):
                    os.unlink(f"/dev/shm/{name}")
                    removed.append(name)
    return removed


def release(names: set[str], wait_s: float = RELEASE_WAIT_S) -> list[str]:
    """Wait until no live process holds any of ``names`` (or ``wait_s`` passes), then remove what is
    left and held by none (:func:`remove_unheld`). Returns the removed names."""
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and any(_held(name) for name in _existing(names)):
        time.sleep(POLL_S)
    return remove_unheld(names)


def release_after_exit(names: set[str]) -> subprocess.Popen | None:
    """Start the detached process that runs :func:`release` on ``names`` once this process (the
    node) is gone; None when there is nothing to do. Called after ``rclpy`` shut down."""
    left = _existing(names)
    if not left:
        return None
    command = [sys.executable, "-m", "nbv_prob_cnn.ros.shm_release", *sorted(left)]
    # its own session: the process group signals that stop the node's graph do not reach it
    return subprocess.Popen(
        command,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        close_fds=True,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="+", help="Fast DDS files in /dev/shm")
    parser.add_argument("--wait-s", type=float, default=RELEASE_WAIT_S, help="longest wait for the holders")
    args = parser.parse_args(argv)
    names = {name for name in args.names if name.startswith(("fastrtps_", "sem.fastrtps_")) and "/" not in name}
    release(names, args.wait_s)  # the node holds them until it is gone: waited for as any holder
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
