"""How the package is divided into rooms, and how far a ``vp2 run`` config travels through it.

Two kinds of figure, for the source tree under ``--src`` (a checkout: ``SRC/src/vp2`` and its
``SRC/tests/test_layering.py``), so that two commits can be compared with the same script::

    python -m benchmarks.checks.architecture_figures --src /path/to/old/checkout
    python -m benchmarks.checks.architecture_figures

**Rooms**, read from the source with ``ast`` by the checkout's own layering test (its
``imported_modules``: imports inside functions and module paths named in strings count). A room
is a sub-package of ``vp2`` (``vp2.spec`` and ``vp2._quiet`` are rooms of one module each, the
package's ``__init__`` is ``vp2``). Per room: modules and lines. An arrow is a module importing
a module of another room; *back arrows* go from a room to a later one in the checkout's
``STAGES``; *cycles* are the strongly connected sets of modules, and of rooms. ``--regroup
PATTERN=ROOM`` counts the modules ``PATTERN`` names (a module, a package or a shell pattern) as
``ROOM``: an old tree split the way a new one is, to see which cycles that split would make::

    python -m benchmarks.checks.architecture_figures --src OLD --no-trace \
        --regroup 'vp2.benchmark.*oracle*=oracle' --regroup 'vp2.benchmark.diag*=diagnose'

**The config's path**: ``vp2 run --model repeat_last_frame --tasks robodesk/push_red
--num-instances 1 --seeds 0 --no-progress`` (one trial, in this process: ``--workers 1``) run
through ``vp2.cli.main`` under :func:`sys.setprofile`, in a child process importing the
checkout's ``vp2``. The config is every ``RunConfig`` instance (the command's, its copies,
the one read back from ``config.yaml``); its *parts* are the values of its fields that are
objects with an identity (the planner's ``PlannerConfig``, tuples, dicts), not strings or
numbers. Then:

* **stops**: the vp2 functions called with the config or a part as an argument (``self``
  included); each function counts once, in the order of its first such call (*calls* counts
  every call);
* **files**: the distinct vp2 source files of those stops;
* **climbs back**: along the stops in that order, the times the path enters a file it had
  already left (and the same between rooms);
* **pre-check stops**: the stops made below the runner's diagnosis pre-check
  (``precheck_model``);
* **vp2 files entered**: every vp2 source file with a function called during the command.
"""

from __future__ import annotations

import argparse
import collections
import fnmatch
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.common import argument_parser

REPO = Path(__file__).resolve().parents[2]
#: The traced command (``--out`` is added).
RUN_ARGS = ["run", "--model", "repeat_last_frame", "--tasks", "robodesk/push_red",
            "--num-instances", "1", "--seeds", "0", "--no-progress", "--workers", "1"]
SCALARS = (str, bytes, int, float, bool, type(None))


# --------------------------------------------------------------------------- rooms


def layering_test(src: Path) -> Any:
    """The checkout's ``tests/test_layering.py``, loaded as a module (its ``SRC`` is its own)."""
    path = src / "tests" / "test_layering.py"
    spec = importlib.util.spec_from_file_location(f"_layering_{abs(hash(str(src)))}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def room_of(module: str, regroup: dict[str, str]) -> str:
    """The room of ``module``: its sub-package of vp2, unless a ``--regroup`` pattern (a module,
    a package, or a shell pattern such as ``vp2.models.zoo*``) names another."""
    for pattern, room in sorted(regroup.items(), key=lambda kv: -len(kv[0])):
        if fnmatch.fnmatchcase(module, pattern) or fnmatch.fnmatchcase(module, pattern + ".*"):
            return room
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected sets of more than one node (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def room_figures(src: Path, regroup: dict[str, str]) -> dict[str, Any]:
    layering = layering_test(src)
    paths = layering.modules()
    graph = layering.graph()
    stages: dict[str, int] = dict(layering.STAGES)
    shared = set(layering.SHARED)
    rooms: dict[str, dict[str, int]] = collections.defaultdict(lambda: {"modules": 0, "lines": 0})
    for name, path in paths.items():
        room = rooms[room_of(name, regroup)]
        room["modules"] += 1
        room["lines"] += len(path.read_text().splitlines())
    arrows: collections.Counter[tuple[str, str]] = collections.Counter()
    back: list[str] = []
    room_graph: dict[str, set[str]] = collections.defaultdict(set)
    for name, deps in graph.items():
        a = room_of(name, regroup)
        for dep in deps:
            b = room_of(dep, regroup)
            if a == b:
                continue
            arrows[(a, b)] += 1
            room_graph[a].add(b)
            sa, sb = stages.get(a), stages.get("envs" if b == "vp2" else b)
            if a not in shared and b not in shared and sa is not None and sb is not None and sb > sa:
                back.append(f"{name} ({a}) -> {dep} ({b})")
    return {
        "rooms": dict(sorted(rooms.items())),
        "arrows": {f"{a} -> {b}": n for (a, b), n in sorted(arrows.items())},
        "room_pairs": len(arrows),
        "module_arrows": sum(arrows.values()),
        "back_arrows": back,
        "module_cycles": strongly_connected(graph),
        "room_cycles": strongly_connected(room_graph),
        "stages": stages,
    }


# --------------------------------------------------------------------------- the config's path


def _non_empty(value: Any) -> bool:
    """Empty containers are left out: ``()`` is one object shared by every caller."""
    try:
        return len(value) > 0
    except TypeError:
        return True


class ConfigTracer:
    """The profile function: records the vp2 calls that receive the run's config or its parts."""

    def __init__(self, package_dir: str) -> None:
        self.package_dir = package_dir
        self.keep: list[Any] = []  # holds every tracked object, so that no id is reused
        self.tracked: set[int] = set()
        self.first: dict[tuple[str, str], int] = {}  # stop -> order of its first call
        self.stops: list[tuple[str, str, bool]] = []  # (file, function, below the pre-check)
        self.calls = 0
        self.files_entered: set[str] = set()

    def track(self, obj: Any) -> bool:
        """Whether ``obj`` is the config or one of its parts (a new config is taken in)."""
        if isinstance(obj, SCALARS):
            return False
        if id(obj) in self.tracked:
            return True
        if type(obj).__name__ != "RunConfig" or not hasattr(obj, "__dataclass_fields__"):
            return False
        self.keep.append(obj)
        self.tracked.add(id(obj))
        for field in obj.__dataclass_fields__:
            value = getattr(obj, field, None)
            if not isinstance(value, SCALARS) and _non_empty(value) and id(value) not in self.tracked:
                self.keep.append(value)
                self.tracked.add(id(value))
        return True

    def receives(self, frame: Any) -> bool:
        """Whether the function of ``frame``, just called, got the config or a part (also
        inside its ``*args`` and ``**kwargs``)."""
        code = frame.f_code
        named = code.co_argcount + code.co_kwonlyargcount
        varargs, varkw = bool(code.co_flags & 0x04), bool(code.co_flags & 0x08)
        local = frame.f_locals
        for i, name in enumerate(code.co_varnames[:named + varargs + varkw]):
            value = local.get(name)
            if self.track(value):
                return True
            if varargs and i == named and any(self.track(v) for v in value or ()):
                return True
            if varkw and i == named + varargs and any(self.track(v) for v in (value or {}).values()):
                return True
        return False

    def __call__(self, frame: Any, event: str, arg: Any) -> None:
        if event != "call":
            return
        file = frame.f_code.co_filename
        if not file.startswith(self.package_dir):
            return
        self.files_entered.add(file)
        if not self.receives(frame):
            return
        self.calls += 1
        key = (file, getattr(frame.f_code, "co_qualname", frame.f_code.co_name))
        if key in self.first:
            return
        self.first[key] = len(self.first)
        below, f = False, frame.f_back
        while f is not None:
            if f.f_code.co_name == "precheck_model":
                below = True
                break
            f = f.f_back
        self.stops.append((file, key[1], below))


def climbs_back(sequence: list[str]) -> int:
    """How often ``sequence`` (consecutive repeats merged) enters an item it had already left."""
    climbs, left, previous = 0, set(), None
    for item in sequence:
        if item != previous:
            climbs += item in left
            if previous is not None:
                left.add(previous)
            previous = item
    return climbs


def trace_run(out: Path) -> dict[str, Any]:
    """Runs :data:`RUN_ARGS` in this process under the tracer (the child's side)."""
    import threading

    import vp2
    from vp2 import cli

    package_dir = str(Path(vp2.__file__).resolve().parent) + os.sep
    tracer = ConfigTracer(package_dir)
    threading.setprofile(tracer)
    sys.setprofile(tracer)
    try:
        rc = cli.main([*RUN_ARGS, "--out", str(out)])
    finally:
        sys.setprofile(None)
        threading.setprofile(None)
    relative = [(str(Path(f).relative_to(package_dir)), name, below)
                for f, name, below in tracer.stops]
    path_files = [f for f, _, _ in relative]
    path_rooms = [Path(f).parts[0] if len(Path(f).parts) > 1 else Path(f).stem
                  for f in path_files]
    return {
        "vp2": package_dir,
        "rc": rc,
        "stops": len(relative),
        "calls": tracer.calls,
        "files": len(set(path_files)),
        "climbs_back": climbs_back(path_files),
        "rooms": len(set(path_rooms)),
        "room_climbs_back": climbs_back(path_rooms),
        "precheck_stops": sum(below for _, _, below in relative),
        "files_entered": len(tracer.files_entered),
        "path": [f"{f}:{name}" + (" (pre-check)" if below else "") for f, name, below in relative],
    }


def config_path(src: Path) -> dict[str, Any]:
    """:func:`trace_run` in a child process that imports the checkout's vp2."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(src / "src"), str(REPO)])}
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.run(
            [sys.executable, "-m", "benchmarks.checks.architecture_figures", "--trace-child",
             str(Path(tmp) / "run")], env=env, cwd=tmp, capture_output=True, text=True,
        )
    if proc.returncode:
        raise SystemExit(f"the traced run failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    expected = str((src / "src" / "vp2").resolve()) + os.sep
    if result["vp2"] != expected:
        raise SystemExit(f"the traced run imported vp2 from {result['vp2']}, not {expected}")
    return result


# --------------------------------------------------------------------------- output


def print_figures(src: Path, rooms: dict[str, Any], path: dict[str, Any] | None) -> None:
    print(f"## {src}\n")
    print("| room | modules | lines |\n|---|---:|---:|")
    for room, f in rooms["rooms"].items():
        print(f"| {room} | {f['modules']} | {f['lines']} |")
    print(f"\n{rooms['module_arrows']} import arrows between rooms, {rooms['room_pairs']} room "
          f"pairs; back arrows: {len(rooms['back_arrows'])}; module cycles: "
          f"{len(rooms['module_cycles'])}; room cycles: {rooms['room_cycles'] or 'none'}\n")
    for line in rooms["back_arrows"]:
        print(f"- back: {line}")
    print("| from -> to | arrows |\n|---|---:|")
    for pair, n in rooms["arrows"].items():
        print(f"| {pair} | {n} |")
    if path is None:
        return
    print(f"\n`vp2 {' '.join(RUN_ARGS)}` (rc {path['rc']}): {path['stops']} stops "
          f"({path['calls']} calls) in {path['files']} files, {path['climbs_back']} climbs back "
          f"(in {path['rooms']} rooms, {path['room_climbs_back']} climbs back between rooms), "
          f"{path['precheck_stops']} stops in the pre-check; {path['files_entered']} vp2 files "
          "entered\n")
    for i, stop in enumerate(path["path"], 1):
        print(f"{i:3d}. {stop}")


def main() -> int:
    ap = argument_parser(__spec__.name, __doc__, full_doc=True)
    ap.add_argument("--src", type=Path, default=REPO,
                    help="the checkout to measure (default: this one)")
    ap.add_argument("--regroup", action="append", default=[], metavar="PATTERN=ROOM",
                    help="count the modules PATTERN names (a module, a package, or a shell pattern "
                    "such as 'vp2.models.zoo*') as ROOM")
    ap.add_argument("--no-trace", action="store_true", help="the rooms only, not the run")
    ap.add_argument("--json", type=Path, help="also write the figures to this file")
    ap.add_argument("--trace-child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.trace_child:
        print(json.dumps(trace_run(Path(args.trace_child))))
        return 0
    src = args.src.resolve()
    if not (src / "src" / "vp2").is_dir() or not (src / "tests" / "test_layering.py").is_file():
        ap.error(f"--src {src}: not a vp2 checkout (needs src/vp2 and tests/test_layering.py)")
    regroup = {}
    for item in args.regroup:
        pattern, sep, room = item.partition("=")
        if not sep or not pattern.startswith("vp2.") or not room:
            ap.error(f"--regroup {item!r}: write PATTERN=ROOM, e.g. 'vp2.models.zoo*=zoo'")
        regroup[pattern] = room
    rooms = room_figures(src, regroup)
    path = None if args.no_trace else config_path(src)
    print_figures(src, rooms, path)
    if args.json:
        args.json.write_text(json.dumps({"src": str(src), "regroup": regroup, "rooms": rooms,
                                         "config_path": path}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
