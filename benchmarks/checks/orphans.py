"""How soon do a killed vp2 process's children end?

Starts a parent process holding a pool of two vp2 workers (``spawn_pool``) and a manager
(``spawn_manager``), SIGKILLs it (as the OOM killer would) and times, per repeat, how long its
three children live on; then the same with Python's own ``ProcessPoolExecutor`` and
``SyncManager`` for comparison (their children never end: they are killed after ``--limit``
seconds and reported as such). Linux (reads /proc)::

    python -m benchmarks.checks.orphans --repeats 3
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from benchmarks.common import argument_parser, print_header

REPO = Path(__file__).resolve().parents[2]

#: The parent: a pool of two workers (each answers with its pid) and a manager; prints the
#: three pids as JSON and waits to be killed. ``{pool}``/``{manager}``: how they are started.
PARENT = textwrap.dedent("""
    import json, multiprocessing as mp, time
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing.managers import SyncManager
    from benchmarks.checks.orphans import sleep_then_pid
    from vp2.utils.executors import spawn_manager, spawn_pool
    pool = {pool}
    pids = set()
    while len(pids) < 2:  # two tasks at a time until both workers have answered
        pids |= {{f.result() for f in [pool.submit(sleep_then_pid, 0.5) for _ in range(2)]}}
    manager = {manager}
    print(json.dumps({{"workers": sorted(pids), "manager": manager._process.pid}}), flush=True)
    time.sleep(600)
""")
STARTS = {
    "vp2": ("spawn_pool(2)", "spawn_manager()"),
    "python": ('ProcessPoolExecutor(2, mp_context=mp.get_context("spawn"))',
               'SyncManager(ctx=mp.get_context("spawn")); manager.start()'),
}


def sleep_then_pid(seconds: float) -> int:
    """A pool task: sleeps, then returns the worker's pid."""
    time.sleep(seconds)
    return os.getpid()


def parent_script(kind: str = "vp2") -> str:
    pool, manager = STARTS[kind]
    return PARENT.format(pool=pool, manager=manager)


def alive(pid: int) -> bool:
    """``pid`` exists and is not a zombie."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return text[text.rindex(")") + 2] != "Z"


def start_parent(kind: str = "vp2") -> tuple[subprocess.Popen[str], list[int]]:
    """The parent process and its three children's pids (two workers, the manager)."""
    proc = subprocess.Popen([sys.executable, "-c", parent_script(kind)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, cwd=REPO)  # fmt: skip
    started = json.loads(proc.stdout.readline())  # type: ignore[union-attr]
    return proc, [*started["workers"], started["manager"]]


def time_to_end(kind: str, limit: float) -> float | None:
    """Seconds from SIGKILL of the parent until its children are gone (``None``: still alive
    after ``limit`` s; they are killed then)."""
    proc, pids = start_parent(kind)
    start = time.monotonic()
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    while any(alive(p) for p in pids):
        if time.monotonic() - start > limit:
            for p in pids:
                if alive(p):
                    os.kill(p, signal.SIGKILL)
            return None
        time.sleep(0.02)
    return time.monotonic() - start


def main() -> None:
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--limit", type=float, default=10.0, help="seconds to wait for an end")
    args = parser.parse_args()
    print_header(__spec__.name, f"Python {sys.version.split()[0]}")
    for kind in STARTS:
        times = [time_to_end(kind, args.limit) for _ in range(args.repeats)]
        shown = ", ".join(f"{t:.2f} s" if t is not None else f"alive after {args.limit:g} s"
                          for t in times)  # fmt: skip
        print(f"{kind}: children of a SIGKILLed parent end after: {shown}")


if __name__ == "__main__":
    main()
