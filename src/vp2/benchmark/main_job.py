"""The README's main job: a real, small evaluation on the shipped defaults (``vp2 main``).

It runs the benchmark (:func:`vp2.benchmark.run_benchmark`) for each of a few agents on the
first instance(s) of every task category of the shipped suite:

* the shipped small models (:data:`SHIPPED_MODELS`, one per environment whose checkpoint is in
  the package, as one agent: :func:`shipped_model`),
* the repeat-last-frame baseline (a lower bound: every plan gets the same cost),
* the random-action agent (a lower bound that ignores observations),

and writes one run directory per agent under ``out`` (trials, GIFs, summaries, resumable),
``tasks.png`` (a contact sheet of the tasks' start images) and ``main.md``: one table with a
column per agent and one per shipped oracle table that normalises an agent's score (the table
of the agent's planner samples, :mod:`vp2.oracle.shipped`), with a line naming the
table (or why there is none) per agent. Default sizes keep it within 15 minutes on a 2-core CPU; the deviations
from the SPEC protocol (one seed, the model's planner samples) are printed with the table.

The main job composes benchmark runs, so it lives with them; the HTML report of each run (a
later stage, :mod:`vp2.report`) comes in as the ``after_run`` hook that ``vp2 main`` passes.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

from vp2 import spec
from vp2.benchmark.runner import RunResult, run_benchmark
from vp2.models.zoo import ZooCard, ZooError, get_card
from vp2.oracle.shipped import (
    NO_SHIPPED_ORACLE,
    OracleMatch,
    OracleTable,
    ShippedOracle,
    load_shipped_oracle,
)
from vp2.planning.planner import PlannerConfig
from vp2.run.config import RunConfig
from vp2.run.results import Summary
from vp2.run.run_dir import GIF_DIR, SUMMARY_FILE, TRIALS_FILE, RunDir
from vp2.utils.io import atomic_path

log = logging.getLogger(__name__)

#: The shipped small models: per environment, the entry of the package's model zoo
#: (vp2/assets/zoo) whose card names the checkpoint (in vp2/assets/models) and its sha256.
#: Each plans only in the environment it was trained on. The tabletop's is the 1/16 SVG' at
#: 60 core-minutes, chosen by control: 14 of 36 trials of the size figure's protocol against
#: 5 of 36 for the 1/8 model of 30 core-minutes it replaced (docs/models.md).
SHIPPED_MODELS: dict[str, str] = {
    "robodesk": "svg_prime-tiny-robodesk",
    "tabletop": "svg_prime-tabletop-m0.0625-60min",
}
#: The model spec of the main job's model agent: :func:`shipped_model`, which builds the
#: shipped checkpoint of whichever environment a trial is in.
SHIPPED_MODEL_SPEC = "vp2.benchmark.main_job:shipped_model"
#: The agents the main job can run (all by default).
AGENTS: tuple[str, ...] = ("model", "repeat_last_frame", "random")


def shipped_card(env: str, name: str | None = None) -> ZooCard | None:
    """The zoo card of ``env``'s shipped small model (or of the package's zoo entry ``name``),
    or ``None`` if it is not installed (the package's zoo, whatever ``$VP2_ZOO_DIR`` names)."""
    if name is None and env not in SHIPPED_MODELS:
        return None
    try:
        zoo = Path(str(resources.files("vp2") / "assets" / "zoo"))
        card = get_card(name or SHIPPED_MODELS[env], zoo, verify=False)
    except ZooError:
        return None
    return card if card.checkpoint_path.is_file() else None


def shipped_model_envs() -> tuple[str, ...]:
    """The environments with an installed shipped model."""
    return tuple(env for env in SHIPPED_MODELS if shipped_card(env) is not None)


def shipped_model(env: str, action_dim: int, device: str = "cpu", robodesk: str | None = None,
                  tabletop: str | None = None) -> Any:
    """The shipped small model of ``env``: its zoo card's checkpoint, checked against the card.

    ``robodesk`` / ``tabletop`` name the package's zoo entry to use in that environment
    (default: :data:`SHIPPED_MODELS`). The main job passes them as model arguments, so that
    they are part of its runs' protocol: a run directory made with other shipped models does
    not resume with these.

    Raises:
        ValueError: no shipped model for ``env`` is installed.
        ZooError: its checkpoint is not the one the card describes.
    """
    import torch

    from vp2.run.model_spec import ModelSpec, resolve_model

    card = shipped_card(env, {"robodesk": robodesk, "tabletop": tabletop}.get(env))
    if card is None:
        raise ValueError(f"no shipped model for {env!r} in vp2/assets (shipped for: "
                         f"{', '.join(shipped_model_envs()) or 'none'})")
    spec = ModelSpec.parse(f"{card.family}:{card.verify()}")
    return resolve_model(spec, {}, env=env, action_dim=action_dim, device=torch.device(device))


@dataclasses.dataclass(frozen=True)
class MainJobConfig:
    """Settings of ``vp2 main`` (one field per flag).

    Attributes:
        out: Output directory.
        num_instances: First instances of each task category.
        seeds: Control-run seeds.
        tasks: Task categories or environment names (empty: all 11).
        model_samples: Planner samples per step for the learned model (``None``: SPEC 200/800).
            Lower by default so that the model's forward passes fit the time budget on a CPU.
        workers: Trial processes.
        agents: Which of ``"model"``, ``"repeat_last_frame"``, ``"random"`` to run.
        resume: Continue the run directories instead of refusing existing ones.
        suite: Task suite file (``None``: the shipped suite).
        num_steps: Control steps per trial (SPEC: 15; fewer only for tests).
    """

    out: str = "outputs/main"
    num_instances: int = 1
    seeds: tuple[int, ...] = (0,)
    tasks: tuple[str, ...] = ()
    model_samples: int | None = spec.MAIN_JOB_NUM_SAMPLES
    workers: int = 2
    agents: tuple[str, ...] = AGENTS
    resume: bool = True
    suite: str | None = None
    num_steps: int = spec.NUM_CONTROL_STEPS


def _run_configs(config: MainJobConfig) -> dict[str, RunConfig]:
    common = dict(tasks=config.tasks, num_instances=config.num_instances, seeds=config.seeds,
                  workers=config.workers, resume=config.resume, max_retries=1,
                  suite=config.suite, num_steps=config.num_steps)
    out = Path(config.out)
    runs: dict[str, RunConfig] = {}
    if "model" in config.agents:
        envs = shipped_model_envs()
        model_tasks = tuple(t for t in config.tasks if t.split("/")[0] in envs)
        if not envs:
            log.warning("no shipped model is installed (vp2/assets/models); skipping it")
        elif config.tasks and not model_tasks:
            log.info("no %s task selected: the shipped model is not run", " or ".join(envs))
        else:
            runs[shipped_card(envs[0]).family] = RunConfig(
                model=SHIPPED_MODEL_SPEC, out=str(out / "model"),
                model_args={env: SHIPPED_MODELS[env] for env in envs},
                planner=PlannerConfig(num_samples=config.model_samples),
                **{**common, "tasks": model_tasks or envs})
    if "repeat_last_frame" in config.agents:
        runs["repeat_last_frame"] = RunConfig(
            model="repeat_last_frame", out=str(out / "repeat_last_frame"), **common)
    if "random" in config.agents:
        runs["random actions"] = RunConfig(
            model="none", agent="random", out=str(out / "random"), save_gifs=False, **common)
    return runs


def _cell(summary: Summary, task: str) -> str:
    for row in summary.tasks:
        if row.task == task:
            return f"{100 * row.mean:.0f}% ({row.num_trials})"
    return "-"


def _oracle_columns(
    results: dict[str, RunResult], shipped: ShippedOracle | None
) -> tuple[dict[str, OracleMatch], dict[str, OracleTable]]:
    """Each agent's match against the shipped tables, and the tables they use (columns)."""
    if shipped is None:
        return {}, {}
    matches = {n: shipped.match(r.records, r.config.planner) for n, r in results.items()}
    used: dict[str, OracleTable] = {}
    for m in matches.values():
        for table in m.tables.values():
            used.setdefault(table.name, table)
    return matches, used


def _oracle_notes(matches: dict[str, OracleMatch]) -> list[str]:
    """Which table normalised each agent (agents with the same line share it), and why
    tasks were left out."""
    lines: dict[str, list[str]] = {}
    for name, m in matches.items():
        if m.tasks:
            lines.setdefault(f"normalised by the {m.source()}", []).append(name)
            for note in m.notes:
                lines.setdefault(note, []).append(name)
        else:
            lines.setdefault(f"not oracle-normalised: {'; '.join(m.notes)}", []).append(name)
    return [f"- {', '.join(names)}: {line}" for line, names in lines.items()]


def comparison_table(results: dict[str, RunResult], shipped: ShippedOracle | None = None) -> str:
    """Markdown: one row per task category, one column per agent (success, trials), and with
    a shipped oracle a column per table that normalises some agent (the table of the agent's
    planner samples, :meth:`ShippedOracle.match`) and a row of each agent's normalised score."""
    names = list(results)
    tasks: list[str] = []
    for r in results.values():
        tasks += [row.task for row in r.summary.tasks if row.task not in tasks]
    matches, tables = _oracle_columns(results, shipped)
    cols = names + [f"oracle {t.name} ({t.samples} samples)" for t in tables.values()]
    lines = ["| task | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    shown: dict[str, list[float]] = {name: [] for name in tables}
    for task in tasks:
        cells = [_cell(results[n].summary, task) for n in names]
        for name, table in tables.items():
            if any(m.tables.get(task) is table for m in matches.values()):
                o = table.tasks[task]
                shown[name].append(o.rate)
                cells.append(f"{100 * o.rate:.0f}% ({o.trials})")
            else:
                cells.append("-")
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    cells = [f"**{100 * results[n].summary.mean:.0f}%**" for n in names]
    cells += [f"**{100 * sum(v) / len(v):.0f}%**" if v else "-" for v in shown.values()]
    lines.append("| **mean over the agent's tasks** | " + " | ".join(cells) + " |")
    if shipped is not None:
        scores = [results[n].summary.normalised for n in names]
        lines.append("| **oracle-normalised score** | "
                     + " | ".join("-" if x is None else f"**{x:.2f}**" for x in scores)
                     + " |" + " |" * len(tables))
    notes = _oracle_notes(matches) if shipped is not None else [f"- {NO_SHIPPED_ORACLE}"]
    for name, r in results.items():
        dev = r.config.deviations()
        if dev:
            notes.append(f"- {name}: not the SPEC protocol: {'; '.join(dev)}")
        if r.num_errors:
            notes.append(f"- {name}: {r.num_errors} trial(s) ended in an error "
                         f"(see {RunDir(r.run_dir).trials_file})")
    return "\n".join(lines + ([""] + notes if notes else []))


def _took(name: str, seconds: float, result: RunResult) -> str:
    """``"svg_prime 4.2 min (11 trials run)"``; a resumed run says what it found done."""
    done = f", {result.num_skipped} done earlier" if result.num_skipped else ""
    return f"{name} {seconds / 60:.1f} min ({result.num_run} trials run{done})"


def run_main_job(
    config: MainJobConfig,
    gallery: bool = True,
    after_run: Callable[[Path], None] | None = None,
) -> tuple[str, Path]:
    """Runs the main job; returns the comparison table and the path of ``main.md``.

    ``after_run`` is passed to every :func:`~vp2.benchmark.runner.run_benchmark` (``vp2 main``
    passes :func:`vp2.report.page.write_run_report`: a ``report.html`` per run directory).
    """
    run_configs = _run_configs(config)
    for run_config in run_configs.values():  # every setting checked before anything is written
        run_config.validate()
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    if gallery:
        from vp2.envs.gallery import render_gallery

        render_gallery(out)
    results: dict[str, RunResult] = {}
    timings: dict[str, float] = {}
    for name, run_config in run_configs.items():
        print(f"== {name}: {run_config.out}", flush=True)
        t0 = time.perf_counter()
        results[name] = run_benchmark(run_config, after_run=after_run)
        timings[name] = time.perf_counter() - t0
    table = comparison_table(results, load_shipped_oracle())
    took = ", ".join(_took(n, t, results[n]) for n, t in timings.items())
    text = (f"# vp2 main: success per task category\n\n{table}\n\n"
            f"Success = the task's criterion held at some step of a 15-step trial "
            f"(cell: success rate (trials)). Wall time: {took}.\n\n"
            + "\n".join(f"- {n}: `{r.run_dir}` ({SUMMARY_FILE}, {TRIALS_FILE}, {GIF_DIR}/)"
                        for n, r in results.items()) + "\n")
    path = out / "main.md"
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)
    return table, path

