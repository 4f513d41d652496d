"""shm_release without ROS: which files are a process's own, and that they are removed only once no
other process holds them (stand-in files in /dev/shm, a child process as their holder)."""

from __future__ import annotations

import subprocess
import sys
import time
import uuid
from pathlib import Path

from nbv_prob_cnn.ros.graph import wait_for
from nbv_prob_cnn.ros.shm_release import own_files, release, remove_unheld

SHM = Path("/dev/shm")


def test_own_files_are_those_with_a_held_lock_file():
    mapped = {
        "fastrtps_0a1b", "fastrtps_0a1b_el",  # own data segment
        "fastrtps_port7411", "fastrtps_port7411_el", "sem.fastrtps_port7411_mutex",  # own listening port
        "fastrtps_9f9f", "fastrtps_port7413", "sem.fastrtps_port7413_mutex",  # a peer's segment and port
    }  # fmt: skip
    assert own_files(mapped) == {
        "fastrtps_0a1b", "fastrtps_0a1b_el", "fastrtps_port7411", "fastrtps_port7411_el", "sem.fastrtps_port7411_mutex",
    }  # fmt: skip


def _stand_in_port() -> tuple[str, set[str]]:
    port = f"fastrtps_port9{uuid.uuid4().int % 10**8:08d}"  # no real port has 9 digits
    names = {port, port + "_el"}
    for name in names:
        (SHM / name).write_bytes(b"x")
    return port, names


def _holder(name: str, seconds: float) -> subprocess.Popen:
    code = f"import time; f = open('/dev/shm/{name}'); print('open', flush=True); time.sleep({seconds})"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "open"
    return proc


def test_a_port_held_by_another_process_is_kept_with_its_lock_file():
    port, names = _stand_in_port()
    holder = _holder(port, 30)
    try:
        assert remove_unheld(names) == []
        assert all((SHM / name).exists() for name in names)
    finally:
        holder.kill()
        holder.wait()
    assert sorted(remove_unheld(names)) == sorted(names)
    assert not any((SHM / name).exists() for name in names)


def test_release_waits_for_the_last_holder_then_removes():
    port, names = _stand_in_port()
    holder = _holder(port + "_el", 1.0)
    start = time.monotonic()
    removed = release(names, wait_s=20.0)
    assert holder.wait(5) == 0
    assert sorted(removed) == sorted(names) and time.monotonic() - start >= 0.5  # waited for the holder
    assert not any((SHM / name).exists() for name in names)


def test_release_leaves_what_is_still_held_when_its_wait_ends():
    port, names = _stand_in_port()
    holder = _holder(port, 30)
    try:
        assert release(names, wait_s=0.3) == []
        assert (SHM / port).exists()
    finally:
        holder.kill()
        holder.wait()
    assert wait_for(lambda: sorted(remove_unheld(names)) == sorted(names) or not (SHM / port).exists(), 5.0)
