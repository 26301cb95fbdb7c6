"""Which success classifier each RoboDesk task plans with: the registry and the shipped files.

The RoboDesk planning cost (SPEC §6) looks a task's classifier up in :data:`CLASSIFIERS`, by
the classifier key the task's registry entry names (``Task.classifier`` of
:data:`vp2.envs.tasks.TASKS`; the key is the task's name). The classifiers shipped in
``vp2/assets/classifiers/<task>.pt`` (or, with ``$VP2_CLASSIFIERS_DIR`` set, those of that
directory) are registered into it when this module is first imported, so before any planning;
they are loaded on first use. A task without a file keeps the ``pixel_only`` fallback of
:func:`vp2.planning.costs.build_cost`.
"""

from __future__ import annotations

import fcntl
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from vp2.classifiers.checkpoint import load_classifier
from vp2.envs import TASKS, get_task, split_name
from vp2.utils.io import write_json_atomic

#: Where the shipped classifiers live: ``<task>.pt`` (``task`` like ``push_red``) and
#: ``metrics.json``.
ASSETS_DIR = Path(__file__).resolve().parents[1] / "assets" / "classifiers"
#: Environment variable naming another directory of classifier files to plan with instead of
#: the shipped ones (e.g. to compare classifier variants with the oracle).
CLASSIFIERS_ENV_VAR = "VP2_CLASSIFIERS_DIR"
METRICS_FILE = "metrics.json"
#: The tasks that have a success classifier (the 7 RoboDesk tasks), from the task registry.
CLASSIFIER_TASKS: tuple[str, ...] = tuple(
    name for name, task in TASKS.items() if task.classifier is not None
)

#: ``loader(device) -> classifier`` with ``classifier(images (M, 3, H, W) in [0, 1]) -> logits
#: (M,)``. Registered per RoboDesk task.
ClassifierLoader = Callable[[torch.device], Callable[[Tensor], Tensor]]


class ClassifierRegistry:
    """Success classifiers per task, registered by whoever provides them.

    Keys are the classifier keys tasks name (``Task.classifier``, the task's name, e.g.
    ``"robodesk/push_red"``). The classifiers shipped with the package are registered into
    :data:`CLASSIFIERS` when this module is imported (:func:`register_shipped_classifiers`).
    Loaded classifiers are cached per ``(task, device)`` in the process.
    """

    def __init__(self) -> None:
        self._loaders: dict[str, ClassifierLoader] = {}
        self._loaded: dict[tuple[str, str], Callable[[Tensor], Tensor]] = {}

    def register(self, task: str, loader: ClassifierLoader) -> None:
        """Registers (or replaces) the classifier loader of ``task``."""
        split_name(task)
        self._loaders[task] = loader
        self._loaded = {k: v for k, v in self._loaded.items() if k[0] != task}

    def unregister(self, task: str) -> None:
        """Removes a task's classifier (tests, or to force the fallback)."""
        self._loaders.pop(task, None)
        self._loaded = {k: v for k, v in self._loaded.items() if k[0] != task}

    def __contains__(self, task: str) -> bool:
        return task in self._loaders

    def get(self, task: str, device: torch.device) -> Callable[[Tensor], Tensor] | None:
        """The task's classifier on ``device``, or ``None`` if none is registered."""
        if task not in self._loaders:
            return None
        key = (task, str(device))
        if key not in self._loaded:
            self._loaded[key] = self._loaders[task](device)
        return self._loaded[key]


#: The process-wide registry the planning agent looks classifiers up in.
CLASSIFIERS = ClassifierRegistry()


def short_task(task: str) -> str:
    """``"robodesk/push_red"`` or ``"push_red"`` -> ``"push_red"`` (checked)."""
    full = task if "/" in task else f"robodesk/{task}"
    registered = get_task(full)
    if registered.classifier is None:
        raise ValueError(f"{task}: success classifiers exist for RoboDesk tasks only")
    return registered.task


def shipped_path(task: str, directory: str | Path = ASSETS_DIR) -> Path:
    """Where the classifier file of ``task`` lives (whether or not it exists)."""
    return Path(directory) / f"{short_task(task)}.pt"


def register_shipped_classifiers(
    registry: ClassifierRegistry = CLASSIFIERS, directory: str | Path | None = None
) -> list[str]:
    """Registers a loader for every task whose classifier file exists in ``directory``
    (default: ``$VP2_CLASSIFIERS_DIR`` if set, else the shipped ones).

    Cheap (files are only checked for existence; a classifier is loaded on first use by the
    registry). Called with the defaults when this module is imported.

    Returns:
        The registered task names.
    """
    if directory is None:
        directory = os.environ.get(CLASSIFIERS_ENV_VAR) or ASSETS_DIR
        if not Path(directory).is_dir():
            raise FileNotFoundError(
                f"${CLASSIFIERS_ENV_VAR} = {directory} is not a directory of classifier files "
                "(vp2 train-classifier --out DIR writes one); unset it to use the shipped ones"
            )
    registered = []
    for task in CLASSIFIER_TASKS:
        path = shipped_path(task, directory)
        if path.is_file():
            key = TASKS[task].classifier
            registry.register(key, lambda device, path=path: load_classifier(path, device))
            registered.append(task)
    return registered


def checkpoint_name(task: str, arch: str) -> str:
    """``push_red.pt`` for ours (the shipped name), ``push_red.paper.pt`` for the paper's."""
    return f"{short_task(task)}.pt" if arch == "ours" else f"{short_task(task)}.{arch}.pt"


def update_metrics(path: Path, arch: str, task: str, entry: dict[str, Any]) -> None:
    """Merges one ``(arch, task)`` entry into a metrics file (written atomically).

    The read-merge-write holds an exclusive lock on the directory, so that two trainings (say
    ours and the paper's, run as two processes) can share one metrics file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        metrics = json.loads(path.read_text()) if path.exists() else {}
        metrics.setdefault(arch, {})[short_task(task)] = entry
        write_json_atomic(path, metrics)
    finally:
        os.close(fd)  # releases the lock


# The shipped classifiers (or $VP2_CLASSIFIERS_DIR's) are registered, not loaded, on import:
# whoever plans imports this module first, so every planning cost sees them.
register_shipped_classifiers(CLASSIFIERS)
