"""The benchmark runner: model × tasks × instances × seeds, resumable, in parallel.

:func:`run_benchmark` takes a :class:`RunConfig` (one field per ``vp2 run`` flag) and

1. selects the task instances of the suite and the control-run seeds; every trial has the key
   ``(task, instance index, seed)`` and its randomness comes from that key alone;
2. creates the run directory with the resolved ``config.yaml`` (or, with ``resume=True``,
   checks that the protocol settings match the existing one); before the first trial of a
   learned model, :func:`vp2.diagnose.model.precheck_model` measures on a few held-out
   clips whether its predictions depend on the actions, warns if not and keeps the figures in
   ``precheck.json`` (``RunConfig.precheck``);
3. runs the trials not yet in ``trials.jsonl`` in worker processes, each of which builds the
   model once per environment; results stream back to this (driver) process, which alone
   writes files: a GIF per trial, then one appended JSON line;
4. retries a crashed trial (model error, simulator error, dead worker) a bounded number of
   times and otherwise records it as an error, with its traceback, never as a success or a
   failure; but a model that fails at its boundary the same way twice in a row before any
   trial finished stops the run (:class:`ModelFailure`), and a model that does not fit the
   run (action size, gradients for ``cem_gd``/``lbfgs``) is refused before any trial;
5. writes and returns the summary table of the trials its settings cover (records of other
   seeds or instances in the directory are named in a warning, not counted:
   :meth:`~vp2.run.run_dir.RunDir.split_trials`; per task: mean success over seeds with
   min/max, normalised by an oracle run if one is given, else by the shipped oracle's table
   of the run's planner samples, :mod:`vp2.oracle.shipped`; an oracle run itself is
   not normalised), then calls
   the ``after_run`` hook with the run directory (``vp2 run`` and ``vp2 main`` pass the HTML
   report writer, :func:`vp2.report.page.write_run_report`).

The pieces: :mod:`~vp2.run.config` (the run's settings), :mod:`~vp2.run.run_dir`
(:class:`~vp2.run.run_dir.RunDir`: its files and the checks of a resume),
:mod:`~vp2.benchmark.worker` (what runs a trial), :mod:`~vp2.benchmark.gifs`; this module is
the driver loop. A ``--tasks`` environment or ``--num-instances`` beyond what the suite has
runs what it has, with a warning (:func:`selection_notes`).

Parallelism policy: trials are the unit of parallel work. With ``workers > 1`` every trial
process plans serially, and a model that runs its own process pool (the simulator oracle's
``num_workers``) is set to one worker, so processes never nest (``workers × num_workers``
processes would oversubscribe the cores). Model-level parallelism is for a single process:
``workers=1`` and e.g. ``model_args={"num_workers": 4}`` to make each of the oracle's
planning steps faster (lower latency per trial, the same throughput).

Worker processes are a :class:`~vp2.utils.executors.LocalExecutor` pool that survives dead
workers (a trial that kills its worker is charged, its neighbours are re-run). With
``executor="ray"`` the trials run on Ray actors instead (:mod:`vp2.utils.executors`,
docs/scale-out.md), one simulator and one model replica per actor, initialised like a pool
worker; results stream back to this process, which still alone writes files, so a run
resumes the same way under either executor.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import operator
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from vp2.benchmark.gifs import write_trial_gifs
from vp2.benchmark.worker import (
    Job,
    Outcome,
    envs_of,
    init_worker,
    retried_at_once,
    run_in_process,
    run_job,
    worker_died,
)
from vp2.data.suite import TaskInstance, TaskSuite
from vp2.diagnose.model import precheck_model
from vp2.envs import ENV_TASKS
from vp2.oracle.shipped import is_oracle_config, load_shipped_oracle, summarize_run
from vp2.run.config import RunConfig
from vp2.run.model_spec import MODEL_DOCS, check_spec
from vp2.run.results import Summary, format_summary, is_ok, trial_key, trial_keys
from vp2.run.run_dir import Records, RunDir
from vp2.utils.executors import LiveQueue, LocalExecutor, RayExecutor, WorkerLost
from vp2.utils.io import json_safe, write_json_atomic

log = logging.getLogger(__name__)

#: Identical model-boundary failures in a row, before any trial finished, that stop a run.
FAIL_FAST_AFTER = 2


class ModelFailure(RuntimeError):
    """The run stopped because of the model: it does not fit the run (checked before any
    trial), or its first trials failed at the model boundary with the same error. Trials
    finished before stay in the run directory; fix the model and resume."""


@dataclasses.dataclass
class RunResult:
    """What :func:`run_benchmark` returns.

    Attributes:
        run_dir: The run directory.
        config: The run's configuration.
        records: Every record in ``trials.jsonl`` (earlier sessions included).
        summary: Scores of those records.
        num_run: Trials finished in this call (errors included).
        num_skipped: Trials already in ``trials.jsonl`` (resume).
        num_errors: Error records among ``records``.
    """

    run_dir: Path
    config: RunConfig
    records: list[dict[str, Any]]
    summary: Summary
    num_run: int
    num_skipped: int
    num_errors: int

    @property
    def table(self) -> str:
        """The summary as Markdown."""
        return format_summary(self.summary)


# --------------------------------------------------------------------------- trial selection


def select_instances(suite: TaskSuite, config: RunConfig) -> list[TaskInstance]:
    """The suite's instances the run covers, in suite order (:meth:`TaskSuite.select`)."""
    return suite.select(config.tasks, config.num_instances)


def selection_notes(
    suite: TaskSuite, config: RunConfig, instances: Sequence[TaskInstance]
) -> list[str]:
    """What the run asks for that the suite does not have, one line each (the runner logs
    them as warnings; nothing is cut silently): task categories of a ``--tasks`` environment
    the suite lacks, and categories with fewer instances than ``--num-instances``."""
    notes = []
    if config.tasks and all(name in ENV_TASKS for name in config.tasks):
        envs = list(dict.fromkeys(config.tasks))
        absent = [f"{e}/{t}" for e in envs for t in ENV_TASKS[e] if f"{e}/{t}" not in suite.tasks]
        if absent:
            running = len({i.task for i in instances})
            notes.append(
                f"--tasks {' '.join(envs)}: the suite has no instances of {', '.join(absent)}; "
                f"running its other {running} task categor{'y' if running == 1 else 'ies'}"
            )
    if config.num_instances:
        counts = collections.Counter(i.task for i in instances)
        for task, n in counts.items():
            if n < config.num_instances:
                notes.append(
                    f"--num-instances {config.num_instances}: {task} has {n} "
                    f"instance{'s' if n != 1 else ''} in the suite; running "
                    f"{'those' if n != 1 else 'that'} {n}"
                )
    return notes


# --------------------------------------------------------------------------- the driver


def run_benchmark(
    config: RunConfig, after_run: Callable[[Path], None] | None = None
) -> RunResult:
    """Runs (or resumes) a benchmark run; see the module docstring.

    Args:
        config: The run's configuration.
        after_run: Called with the run directory once the summary is written, e.g.
            :func:`vp2.report.page.write_run_report` (what ``vp2 run`` passes: the HTML
            report, ``report.html``). The run's files are complete before it is called.

    Returns:
        A :class:`RunResult` with the records and the summary (also written to
        ``summary.md`` / ``summary.json`` in the run directory).

    Raises:
        ValueError: an invalid config, a model spec that cannot be resolved, or a resume with
            different protocol settings.
        FileExistsError: the output directory holds a run and ``resume`` is off, or files
            that are not a run.
        RuntimeError: the model could not be built in a worker (nothing can run).
        ModelFailure: the model does not fit the run (action size; gradients for
            ``cem_gd``/``lbfgs``), or its first trials failed at the model boundary with the
            same error :data:`FAIL_FAST_AFTER` times in a row (finished trials are kept).
    """
    config.validate()
    if config.agent == "planning":
        check_spec(config.model)
    suite = TaskSuite.load(config.suite)
    instances = select_instances(suite, config)
    for note in selection_notes(suite, config, instances):
        log.warning("%s", note)
    by_key = {(i.task, i.index): i for i in instances}
    keys = trial_keys(instances, config.seeds)
    run = RunDir.prepare(config)
    run_dir = run.path
    existing = run.resume_records(config.retry_errors)
    run.check_same_instances(existing, by_key)
    done = {trial_key(r) for r in existing}
    todo = [k for k in keys if k not in done]
    for message in config.deviations():
        log.warning("not the SPEC protocol: %s", message)

    jobs = [Job(key=k, instance=by_key[k[:2]]) for k in todo]
    if config.precheck and jobs and not existing:  # before the run's first trial
        measures = precheck_model(config, envs_of(jobs))
        if measures:  # the report shows it beside the control score
            write_json_atomic(run.precheck_file, json_safe({"precheck": measures}))
    max_attempts = config.max_retries + 1
    requeue: collections.deque[Job] = collections.deque()
    num_run = successes = finished = 0
    # Model-boundary failures in a row while no trial has finished in this session, and the
    # final error records among them, held back until the streak ends (if the run stops, those
    # trials are not finished: a resume runs them again).
    streak: list[dict[str, Any]] = []
    held: list[dict[str, Any]] = []
    bar = tqdm(total=len(jobs), unit="trial", desc="vp2 run", disable=not config.progress)
    stream = _execute(jobs, config, requeue)
    try:
        with run.trial_log() as trial_log:
            for job, outcome in stream:
                if outcome is None:  # its worker died with it running alone
                    outcome = worker_died(job, config)
                if outcome.fatal:
                    err = outcome.record["error"]
                    if err["where"] == "model_check":
                        raise ModelFailure(
                            f"model {config.model!r} cannot run these tasks: {err['message']}"
                        )
                    raise RuntimeError(
                        f"could not build the model {config.model!r} "
                        f"({err['type']}: {err['message']}):\n{err['traceback']}"
                    )
                record = outcome.record
                failure = (record["error"] or {}).get("model_failure")
                if finished == 0 and failure is not None:
                    same = bool(streak) and _same(streak[-1], failure)
                    streak = [*streak, failure] if same else [failure]
                    if len(streak) >= FAIL_FAST_AFTER:
                        message = _fail_fast_message(config, run, failure, len(streak))
                        raise ModelFailure(message)
                elif streak:
                    streak = []
                    for r in held:
                        trial_log.append(r)
                    held = []
                error = record["error"]
                if error is not None and job.attempt < max_attempts and retried_at_once(error):
                    log.warning(
                        "trial %s failed (attempt %d/%d): %s: %s",
                        job.key,
                        job.attempt,
                        max_attempts,
                        record["error"]["type"],
                        record["error"]["message"],
                    )
                    requeue.append(
                        Job(job.key, job.instance, job.attempt + 1, [*job.errors, record["error"]])
                    )
                    continue
                record["attempts"] = job.attempt
                record["previous_errors"] = job.errors
                if outcome.result is not None and config.save_gifs:
                    write_trial_gifs(run_dir, outcome.result, record)
                if streak:
                    held.append(record)
                else:
                    trial_log.append(record)
                    if record["error"] is None:  # recorded: its progress file is done with
                        run.partial_path(*job.key).unlink(missing_ok=True)
                num_run += 1
                finished += record["error"] is None
                successes += bool(record.get("success"))
                bar.update(1)
                bar.set_postfix(success=f"{successes}/{finished}", errors=num_run - finished)
            for r in held:  # the run ended with a streak shorter than FAIL_FAST_AFTER
                trial_log.append(r)
    finally:
        bar.close()
        stream.close()

    records, outside = run.split_trials(keys)
    notes = [run.outside_note(outside)] if outside else []
    for note in notes:
        log.warning("%s", note)
    summary = _write_summary(run, config, records, notes)
    if after_run is not None:
        after_run(run_dir)
    return RunResult(
        run_dir=run_dir,
        config=config,
        records=records,
        summary=summary,
        num_run=num_run,
        num_skipped=len(keys) - len(todo),
        num_errors=sum(not is_ok(r) for r in records),
    )


def _same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """The same model failure: model, field and what was expected (not the exact values)."""
    keys = ("model", "field", "expected")
    if a.get("expected") == "no exception":  # an exception from predict: its text too
        keys = (*keys, "got")
    return all(a.get(k) == b.get(k) for k in keys)


def _fail_fast_message(
    config: RunConfig, run: RunDir, failure: dict[str, Any], count: int
) -> str:
    kept, run_dir = len(run.trials()), run.path
    return (
        f"stopped: model {failure['model']} ({config.model}) failed its first {count} trial "
        f"attempts the same way, at the model boundary: {failure['field']}: expected "
        f"{failure['expected']}, got {failure['got']}. See {MODEL_DOCS} for the interface. "
        f"{kept} finished trial(s) kept in {run_dir}; fix the model and continue with --resume"
    )


def _write_summary(
    run: RunDir, config: RunConfig, records: Records, notes: Sequence[str] = ()
) -> Summary:
    """Scores the run (normalised as :func:`~vp2.oracle.shipped.summarize_run`
    does it: by the shipped oracle's table of the run's planner samples) and writes
    ``summary.json`` and ``summary.md`` (``notes``: warnings to add)."""
    is_oracle = is_oracle_config(config.to_dict())
    summary = summarize_run(
        records,
        is_oracle=is_oracle,
        oracle_run=config.oracle,
        shipped=None if is_oracle or config.oracle else load_shipped_oracle(),
        planner=config.planner,
    )
    summary.warnings += [f"not the SPEC protocol: {d}" for d in config.deviations()]
    summary.warnings += list(notes)
    run.write_summary(summary)
    return summary


def _execute(
    jobs: list[Job], config: RunConfig, requeue: collections.deque[Job]
) -> Iterator[tuple[Job, Outcome | None]]:
    """Runs the jobs, then the retries the driver puts into ``requeue`` meanwhile; yields
    ``(job, outcome)``, outcome ``None`` if the job's worker died with it (running alone in a
    local pool; every time it ran, on Ray).

    With one local worker the trials run in this process. A local pool re-runs the trials in
    flight when a worker died one at a time, so a trial that kills its worker is identified
    and charged, and its neighbours are not; a charged trial runs alone again on a retry. On
    Ray each actor runs one trial at a time, so a death is charged to the trial that ran, and
    a trial that lost an innocent worker (a node went away) is re-run elsewhere by the
    executor before it counts as an attempt here.
    """
    queue = LiveQueue(jobs, requeue)
    envs = envs_of(jobs)
    if config.executor == "local" and config.workers <= 1:
        yield from run_in_process(queue, config, envs)
        return
    options: dict[str, Any] = {}
    if config.executor == "ray":
        executor: LocalExecutor | RayExecutor = RayExecutor(
            address=config.address,
            workers=config.workers,
            num_cpus=config.num_cpus_per_worker,
            num_gpus=config.num_gpus_per_worker,
        )
        if config.device is None and config.num_gpus_per_worker == 0:
            # An actor without a GPU share must not take a GPU its node has (Ray may leave it
            # visible): the model replicas of such a run belong on the CPU.
            config = dataclasses.replace(config, device="cpu")
    else:
        executor = LocalExecutor(config.workers)
        options["key"] = operator.attrgetter("key")
    with executor:
        results = executor.imap_unordered(
            run_job, queue, init_worker, (config, envs), on_lost="yield", **options
        )
        try:
            for job, outcome in results:
                yield job, None if isinstance(outcome, WorkerLost) else outcome
        finally:
            results.close()
