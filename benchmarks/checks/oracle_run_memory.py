"""Does an oracle run's process stay the same size from trial to trial?

Runs a short simulator-oracle run (``vp2 run --model simulator``, one worker, so trials, the
planner and the oracle's environments share one process) on ``--instances`` instances of one
tabletop category, and prints the process's resident memory (``VmRSS``) after each finished
trial. ``--per-instance-envs`` runs it a second time, in its own process, with the environment
caches keyed as they were before instances shared one environment (by the whole metadata, so a
tabletop instance's texture names build a new environment): the two columns side by side::

    MUJOCO_GL=egl OMP_NUM_THREADS=1 python -m benchmarks.checks.oracle_run_memory --per-instance-envs
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import argument_parser, print_header
from vp2.run.run_dir import RunDir

#: Run in a child process: optionally restores the old cache key, then runs the CLI.
_CHILD = """
import json, sys
if sys.argv[1] == "per-instance":
    from vp2.envs import cache
    from vp2.envs.factory import make_env_from_metadata

    def get(self, env_meta, **make_kwargs):
        key = json.dumps([env_meta, make_kwargs], sort_keys=True)
        return self.get_or_make(key, lambda: make_env_from_metadata(env_meta, **make_kwargs))

    cache.EnvCache.get = get
from vp2.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _rss_mib(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except FileNotFoundError:
        return None
    return None


def measure(mode: str, task: str, instances: int, out: Path) -> list[float]:
    """RSS (MiB) of the run's process after each of its trials."""
    args = ["run", "--model", "simulator", "--tasks", task, "--num-instances", str(instances),
            "--seeds", "0", "--num-samples", "10", "--num-steps", "5", "--workers", "1",
            "--no-progress", "--out", str(out)]
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, mode, *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    trials = RunDir(out).trials_file
    after: list[float] = []
    last = None
    while proc.poll() is None:
        time.sleep(0.5)
        rss = _rss_mib(proc.pid)
        if rss is not None:
            last = rss
        done = sum(1 for _ in trials.open()) if trials.exists() else 0
        while len(after) < done and last is not None:
            after.append(last)
    if proc.returncode != 0:
        raise SystemExit(f"the {mode} run failed (exit {proc.returncode}); run it by hand: "
                         f"vp2 {' '.join(args)}")
    return after


def main(argv: list[str] | None = None) -> int:
    ap = argument_parser(__spec__.name, __doc__)
    ap.add_argument("--task", default="tabletop/push_small_cube")
    ap.add_argument("--instances", type=int, default=8)
    ap.add_argument("--per-instance-envs", action="store_true",
                    help="also run with one environment per instance (the old cache key)")
    args = ap.parse_args(argv)
    print_header(__spec__.name, "vp2 run --model simulator, one worker")
    modes = ["shared"] + (["per-instance"] if args.per_instance_envs else [])
    columns = {}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in modes:
            columns[mode] = measure(mode, args.task, args.instances, Path(tmp) / mode)
    print("| trial | " + " | ".join(f"{m} envs (MiB)" for m in modes) + " |")
    print("|---|" + "---|" * len(modes))
    for i in range(args.instances):
        cells = [f"{columns[m][i]:,.0f}" if i < len(columns[m]) else "" for m in modes]
        print(f"| {i + 1} | " + " | ".join(cells) + " |")
    print(json.dumps({m: [round(x) for x in v] for m, v in columns.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
