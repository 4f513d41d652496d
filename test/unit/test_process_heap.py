"""``limit_heap_retention`` + ``release_free_heap``: freed multi-megabyte blocks go back to the system.

The check runs in fresh processes (mallopt settings are per process) and reads their resident size
from /proc: with glibc's defaults, the classic retention pattern (one large block freed, which
raises the mapping threshold, then large blocks pinned between smaller live ones) keeps the 120 MiB
freed resident; after ``release_free_heap`` (what every node calls each second) they are returned."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys

import pytest

from nbv_prob_cnn.basics.process_heap import heap_tuning_enabled, limit_heap_retention

pytestmark = pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="needs /proc")

PATTERN = r"""
import ctypes, json, os, sys
from nbv_prob_cnn.basics.process_heap import heap_tuning_enabled, limit_heap_retention, release_free_heap
line = limit_heap_retention()
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
page = os.sysconf("SC_PAGE_SIZE")
def rss_mib():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * page / 2**20
block = 3 << 20
first = libc.malloc(4 << 20)
ctypes.memset(first, 1, 4 << 20)
libc.free(first)  # glibc's defaults: the mapping threshold slides up to 4 MiB
big, small = [], []
for _ in range(40):
    p = libc.malloc(block)
    ctypes.memset(p, 1, block)  # resident
    big.append(p)
    small.append(libc.malloc(256 << 10))  # a live block after each large one (too large for old holes)
held = rss_mib()
for p in big:
    libc.free(p)
released = release_free_heap() if heap_tuning_enabled() else False
print(json.dumps({"line": line, "released": released, "returned_mib": held - rss_mib()}))
"""


def returned(tuning: str) -> dict:
    env = {**os.environ, "NBV_HEAP_TUNING": tuning}
    for variable in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_ARENA_MAX"):
        env.pop(variable, None)
    out = subprocess.run([sys.executable, "-c", PATTERN], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def test_freed_blocks_are_returned_with_the_settings_and_kept_without():
    if platform.libc_ver()[0] != "glibc":
        pytest.skip("not glibc")
    default = returned("0")
    tuned = returned("1")
    assert default["line"].endswith("(NBV_HEAP_TUNING=0)") and not default["released"]
    assert default["returned_mib"] < 12.0  # of 40 x 3 MiB freed: the pattern does show the retention
    assert "malloc_arena_max=2" in tuned["line"] and "malloc_trim" in tuned["line"] and tuned["released"]
    assert tuned["returned_mib"] > 110.0  # all returned


def test_the_environment_variable_of_glibc_wins_and_the_switch_turns_it_off():
    line = limit_heap_retention(environ={"MALLOC_ARENA_MAX": "4"})
    assert line.startswith("heap: malloc_arena_max=4 from the environment")
    off = {"NBV_HEAP_TUNING": "0"}
    assert limit_heap_retention(environ=off) == "heap: glibc defaults, no trimming (NBV_HEAP_TUNING=0)"
    assert not heap_tuning_enabled(off)
