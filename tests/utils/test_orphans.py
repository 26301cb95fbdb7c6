"""Worker processes end with their parent, however it ended (SIGKILL, the OOM killer): a
killed run leaves no orphans holding a model's memory (``vp2.utils.executors.local``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests import alive, child_pids, wait_until_gone
from vp2.utils.executors.local import PARENT_CHECK_INTERVAL

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc (Linux)")

# A parent that starts a pool of two workers (each returns its pid) and a manager, prints the
# pids of all three, and waits to be killed.
PARENT = textwrap.dedent("""
    import json, time
    from tests.utils.test_orphans import _sleep_then_pid
    from vp2.utils.executors import spawn_manager, spawn_pool
    pool = spawn_pool(2)
    pids = set()
    while len(pids) < 2:  # two tasks at a time until both workers have answered
        pids |= {f.result() for f in [pool.submit(_sleep_then_pid, 0.5) for _ in range(2)]}
    manager = spawn_manager()
    print(json.dumps({"workers": sorted(pids), "manager": manager._process.pid}), flush=True)
    time.sleep(600)
""")

def test_pool_workers_and_manager_end_when_their_parent_is_killed():
    proc = subprocess.Popen(
        [sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True, cwd=REPO
    )
    try:
        started = json.loads(proc.stdout.readline())
        pids = started["workers"] + [started["manager"]]
        assert len(set(pids)) == 3 and all(alive(p) for p in pids)
        assert set(pids) <= set(child_pids(proc.pid))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert wait_until_gone(pids, timeout=10 * PARENT_CHECK_INTERVAL + 5) == []
    finally:
        proc.kill()
        proc.wait()


def test_a_worker_whose_parent_lives_stays():
    from vp2.utils.executors import spawn_pool

    with spawn_pool(1) as pool:
        pid = pool.submit(os.getpid).result()
        # Past several of its parent checks, it still answers, as the same process.
        assert pool.submit(_sleep_then_pid, 3 * PARENT_CHECK_INTERVAL).result() == pid
        assert alive(pid)
    assert wait_until_gone([pid], timeout=10) == []


def _sleep_then_pid(seconds: float) -> int:
    import time

    time.sleep(seconds)
    return os.getpid()
