"""How much memory do the environments hold, and can a process holding several still fork?

Builds ``--tabletop`` tabletop and ``--robodesk`` RoboDesk environments in one fresh process
(each reset and rendered once, as a trial worker or the simulator oracle's cache holds them),
once with the tabletop's solver arena as vp2 sizes it and once with robosuite's sizes
(``<size nconmax="5000" njmax="5000"/>``), and prints per process: the private address space
(``VmData``), the resident memory (``VmRSS``), the largest anonymous mapping and whether
``os.fork`` succeeds. Linux (with the default heuristic overcommit) refuses to copy a mapping
larger than RAM plus swap, so the largest mapping is what a test process or a trial worker
that starts data-loader processes or a pool must keep small::

    MUJOCO_GL=egl python -m benchmarks.checks.env_memory --tabletop 4 --robodesk 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

from benchmarks.common import argument_parser, print_header


def _status() -> dict[str, int]:
    """``VmData`` and ``VmRSS`` of this process, in MiB."""
    out = {}
    with open("/proc/self/status") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key in ("VmData", "VmRSS"):
                out[key] = int(value.split()[0]) // 1024
    return out


def _largest_anonymous_mapping() -> int:
    """The largest private writable mapping without a file (MiB): adjacent ones merge."""
    largest = 0
    with open("/proc/self/maps") as f:
        for line in f:
            fields = line.split()
            start, end = (int(x, 16) for x in fields[0].split("-"))
            if fields[1] == "rw-p" and len(fields) == 5:
                largest = max(largest, (end - start) >> 20)
    return largest


def measure(tabletop: int, robodesk: int, arena: str) -> dict[str, object]:
    """Builds the environments in this process and measures it (run in a fresh process)."""
    import dataclasses

    from vp2.envs import make_env
    from vp2.envs.tabletop_scene import DEFAULT_SCENE

    scene = DEFAULT_SCENE
    if arena == "robosuite":
        scene = dataclasses.replace(DEFAULT_SCENE, solver_arena=None)
    before = _status()
    envs = []
    for i in range(tabletop):
        env = make_env(f"tabletop/{('push_large_cube', 'push_sphere')[i % 2]}", seed=i, scene=scene)
        env.reset()
        env.render()
        envs.append(env)
    for i in range(robodesk):
        env = make_env(f"robodesk/{('push_red', 'open_drawer')[i % 2]}", seed=i)
        env.reset()
        env.render()
        envs.append(env)
    after = _status()
    try:
        pid = os.fork()
    except OSError as exc:
        forks = f"no ({exc.strerror})"
    else:
        if pid == 0:
            os._exit(0)
        os.waitpid(pid, 0)
        forks = "yes"
    return {
        "arena": arena if arena == "robosuite" else scene.solver_arena,
        "arena_mib": round(envs[0].unwrapped._model.narena / 2**20, 1) if tabletop else None,
        "vmdata_mib": after["VmData"] - before["VmData"],
        "rss_mib": after["VmRSS"] - before["VmRSS"],
        "largest_mapping_mib": _largest_anonymous_mapping(),
        "fork": forks,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--tabletop", type=int, default=4, help="tabletop environments")
    parser.add_argument("--robodesk", type=int, default=2, help="RoboDesk environments")
    parser.add_argument("--child", choices=("vp2", "robosuite"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(measure(args.tabletop, args.robodesk, args.child)))
        return
    ram_gib = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") >> 30
    print_header(__spec__.name, f"{ram_gib} GiB RAM")
    rows = []
    for arena in ("robosuite", "vp2"):
        proc = subprocess.run(
            [sys.executable, "-m", __spec__.name, "--child", arena,
             "--tabletop", str(args.tabletop), "--robodesk", str(args.robodesk)],
            capture_output=True, text=True, check=True,
        )
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    print(f"\n{args.tabletop} tabletop + {args.robodesk} RoboDesk environments, reset and rendered:\n")
    print("| tabletop arena | arena per MjData | address space (VmData) | resident (RSS) "
          "| largest anonymous mapping | fork |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['arena']} | {row['arena_mib']} MiB | {row['vmdata_mib'] / 1024:.1f} GiB "
              f"| {row['rss_mib'] / 1024:.1f} GiB | {row['largest_mapping_mib'] / 1024:.1f} GiB "
              f"| {row['fork']} |")
    ratio = rows[0]["vmdata_mib"] / max(rows[1]["vmdata_mib"], 1)
    print(f"\naddress space, robosuite's sizes / vp2's: {ratio:.1f}x")


if __name__ == "__main__":
    main()
