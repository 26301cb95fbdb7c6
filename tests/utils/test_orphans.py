"""Worker processes end with their parent, however it ended (SIGKILL, the OOM killer): a
killed run leaves no orphans holding a model's memory (``vp2.utils.executors.local``). The
timing is ``python -m benchmarks.checks.orphans`` (docs/measurements.md)."""

from __future__ import annotations

import os
import signal

from benchmarks.checks.orphans import sleep_then_pid, start_parent

from tests import alive, child_pids, wait_until_gone
from vp2.utils.executors.local import PARENT_CHECK_INTERVAL


def test_pool_workers_and_manager_end_when_their_parent_is_killed():
    proc, pids = start_parent("vp2")  # two spawn_pool workers and a spawn_manager
    try:
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
        assert pool.submit(sleep_then_pid, 3 * PARENT_CHECK_INTERVAL).result() == pid
        assert alive(pid)
    assert wait_until_gone([pid], timeout=10) == []
