"""Pictures of the task suite: start and goal images side by side."""

from __future__ import annotations

from pathlib import Path

from PIL import Image

from vp2.data.suite import TaskSuite
from vp2.envs.rendering import contact_sheet


def suite_contact_sheet(
    suite: TaskSuite, task: str, out: str | Path | None = None, max_instances: int = 12
) -> Path:
    """Writes a PNG with, per instance, its initial image and its goal image."""
    instances = suite.for_task(task)[:max_instances]
    if not instances:
        raise ValueError(f"the suite has no instances of {task}; tasks: {', '.join(suite.tasks)}")
    images, labels = [], []
    env = instances[0].make_env(observation_size=None)
    try:
        for inst in instances:
            env.reset_to(inst.init_state)
            images += [env.render(64), inst.goal_image]
            labels += [f"#{inst.index} start", f"#{inst.index} goal"]
    finally:
        env.close()
    out = Path(out) if out else Path("outputs/tasks") / f"{task.replace('/', '_')}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(contact_sheet(images, labels, columns=6, scale=2)).save(out)
    return out
