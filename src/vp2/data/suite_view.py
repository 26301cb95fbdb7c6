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
    for inst in instances:
        # Each instance's own env: tabletop instances differ in their objects' textures.
        env = inst.make_env(observation_size=None)
        try:
            images += [env.render(64), inst.goal_image]
        finally:
            env.close()
        labels += [f"#{inst.index} start ({len(inst.actions)} act.)", f"#{inst.index} goal"]
    out = Path(out) if out else Path("outputs/tasks") / f"{task.replace('/', '_')}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(contact_sheet(images, labels, columns=6, scale=2)).save(out)
    return out
