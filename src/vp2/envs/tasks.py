"""The registry of the benchmark's 11 task categories: one :class:`Task` per ``"<env>/<task>"``.

A :class:`Task` says everything the stages need to know about a category, as plain data: the
environment, the success rule the environment evaluates, the planner's sample count, the form of
the planning cost, the keys of its success classifier and scripted policy, and its share of the
task suite. Later stages resolve the keys in their own registries; nothing here imports a
simulator or a later stage::

    from vp2.envs.tasks import TASKS
    TASKS["robodesk/open_slide"].num_samples      # 800 (SPEC §5)

========================  ==================================================================
who asks                  for what
========================  ==================================================================
``vp2.envs.robodesk``     ``success``, ``target``: the success criterion and dense reward
``vp2.envs.tabletop``     ``target``: the object the task pushes
``vp2.data.policies``     ``policy``, ``target``: the scripted policy of the task suite
``vp2.classifiers``       ``classifier``: which success classifier a task has
``vp2.planning``          ``num_samples`` (planner settings), ``cost``, ``pixel_weight``,
                          ``classifier_weight``, ``classifier`` (the planning cost)
``vp2.data.suite``        ``suite_instances``: instances per category in the suite
========================  ==================================================================
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from vp2 import spec

#: How a task's plans are scored (SPEC §6): ``"pixel"``: ``pixel_weight × pixel SSE``;
#: ``"pixel+classifier"``: that plus ``classifier_weight × (−Σ_t success logit)``.
CostForm = Literal["pixel", "pixel+classifier"]


@dataclasses.dataclass(frozen=True)
class Task:
    """One task category of the benchmark and what every stage needs to know about it.

    Attributes:
        env: Environment name, ``"robodesk"`` or ``"tabletop"``.
        task: Task name within the environment, e.g. ``"push_red"``.
        success: The success rule the environment evaluates (it holds the thresholds).
            RoboDesk: ``"button_pressed"``, ``"slide_open"``, ``"drawer_open"`` or
            ``"off_table"``; tabletop: ``"objects_at_goal"``.
        target: What the task acts on, for the rule and the policy: a button's colour
            (``"red"``), an object (``"flat_block"``, ``"cylinder"``), or ``None``.
        policy: Key of the task's scripted policy in the env's table of
            :mod:`vp2.data.policies`.
        classifier: Key of the task's success classifier in
            :class:`vp2.classifiers.registry.ClassifierRegistry`; ``None`` if the task has none.
        cost: Form of the planning cost, see :data:`CostForm`.
        pixel_weight: Weight of the pixel SSE in the cost.
        classifier_weight: Weight of the classifier term (``None`` for a ``"pixel"`` cost).
        num_samples: Planner samples per step (SPEC §5).
        suite_instances: Instances of the category in the task suite (SPEC §2).
    """

    env: str
    task: str
    success: str
    target: str | None
    policy: str
    classifier: str | None
    cost: CostForm
    pixel_weight: float
    classifier_weight: float | None
    num_samples: int
    suite_instances: int

    def __post_init__(self) -> None:
        if self.cost not in ("pixel", "pixel+classifier"):
            raise ValueError(f"{self.name}: unknown cost form {self.cost!r}")
        with_classifier = self.cost == "pixel+classifier"
        if with_classifier != (self.classifier is not None) or with_classifier != (
            self.classifier_weight is not None
        ):
            raise ValueError(
                f"{self.name}: a 'pixel+classifier' cost needs a classifier key and weight, "
                "a 'pixel' cost neither"
            )

    @property
    def name(self) -> str:
        """The registered name, ``"<env>/<task>"``."""
        return f"{self.env}/{self.task}"


def _robodesk(
    task: str,
    success: str,
    target: str | None,
    policy: str,
    num_samples: int = spec.NUM_SAMPLES,
    classifier_weight: float = spec.ROBODESK_CLASSIFIER_WEIGHT,
) -> Task:
    """A RoboDesk task: SPEC §6 cost with the task's own classifier, 30 suite instances."""
    return Task(
        env="robodesk",
        task=task,
        success=success,
        target=target,
        policy=policy,
        classifier=f"robodesk/{task}",
        cost="pixel+classifier",
        pixel_weight=spec.ROBODESK_PIXEL_WEIGHT,
        classifier_weight=classifier_weight,
        num_samples=num_samples,
        suite_instances=30,
    )


def _tabletop(target: str) -> Task:
    """A tabletop task: push ``target`` to its goal; pixel cost, 25 suite instances."""
    return Task(
        env="tabletop",
        task=f"push_{target}",
        success="objects_at_goal",
        target=target,
        policy="push_object",
        classifier=None,
        cost="pixel",
        pixel_weight=spec.TABLETOP_PIXEL_WEIGHT,
        classifier_weight=None,
        num_samples=spec.NUM_SAMPLES,
        suite_instances=25,
    )


#: The off-table blocks' classifier weight (SPEC §6 allows one per task, from {1, 10, 100, 1000,
#: 10000}, tuned with the oracle on instances the shipped tables do not report): the smallest
#: weight at which the oracle's cost ranks the scripted plan first among the first step's 50
#: candidates on every tuning instance #10-#17 of both blocks, with their "progress"-label
#: classifiers (docs/findings/oracle.md, "The off-table blocks: a progress label").
BLOCK_CLASSIFIER_WEIGHT = 100.0

_ALL: tuple[Task, ...] = (
    _robodesk("push_red", "button_pressed", "red", "push_button"),
    _robodesk("push_green", "button_pressed", "green", "push_button"),
    _robodesk("push_blue", "button_pressed", "blue", "push_button"),
    _robodesk("open_slide", "slide_open", None, "open_slide", spec.LARGE_NUM_SAMPLES),
    _robodesk("open_drawer", "drawer_open", None, "open_drawer", spec.LARGE_NUM_SAMPLES),
    _robodesk("flat_block_off_table", "off_table", "flat_block", "push_off_table",
              classifier_weight=BLOCK_CLASSIFIER_WEIGHT),
    _robodesk("upright_block_off_table", "off_table", "upright_block", "push_off_table",
              classifier_weight=BLOCK_CLASSIFIER_WEIGHT),
    _tabletop("large_cube"),
    _tabletop("small_cube"),
    _tabletop("cylinder"),
    _tabletop("sphere"),
)
#: Every task category by its name ``"<env>/<task>"``, in the benchmark's order.
TASKS: dict[str, Task] = {t.name: t for t in _ALL}
#: All 11 registered task categories, ``"<env>/<task>"``.
TASK_NAMES: tuple[str, ...] = tuple(TASKS)
ENV_NAMES: tuple[str, ...] = tuple(dict.fromkeys(t.env for t in _ALL))
ENV_TASKS: dict[str, tuple[str, ...]] = {
    env: tuple(t.task for t in _ALL if t.env == env) for env in ENV_NAMES
}
ROBODESK_TASKS: tuple[str, ...] = ENV_TASKS["robodesk"]
TABLETOP_TASKS: tuple[str, ...] = ENV_TASKS["tabletop"]


def get_task(name: str) -> Task:
    """The registered :class:`Task` named ``"<env>/<task>"``, with a helpful error."""
    if name not in TASKS:
        raise ValueError(
            f"unknown task {name!r}; registered tasks are: {', '.join(TASK_NAMES)}"
        )
    return TASKS[name]


def split_name(name: str) -> tuple[str, str]:
    """``"robodesk/push_red"`` -> ``("robodesk", "push_red")``, with a helpful error."""
    task = get_task(name)
    return task.env, task.task


__all__ = [
    "ENV_NAMES",
    "ENV_TASKS",
    "ROBODESK_TASKS",
    "TABLETOP_TASKS",
    "TASKS",
    "TASK_NAMES",
    "CostForm",
    "Task",
    "get_task",
    "split_name",
]
