"""Baseline models that know nothing about dynamics.

:class:`RepeatLastFrame` predicts the last context frame ten times. Every candidate gets the
same cost, so the planner executes the mean of its noise: a lower bound for any model that is
useful at all. (The other baseline, uniform random actions, is an agent, not a model:
:class:`vp2.planning.agent.RandomActions`.)
"""

from __future__ import annotations

from typing import Any

from torch import Tensor

from vp2 import spec


class RepeatLastFrame:
    """Predicts the last context frame for every future step.

    Args:
        action_dim: ``A`` of the environment it is used with.
        image_size: Side of the frames.
        max_batch_size: Largest batch per call (the prediction is a view, so any size works).
    """

    name = "repeat_last_frame"
    num_context = spec.NUM_CONTEXT
    num_future = spec.NUM_FUTURE

    def __init__(
        self, action_dim: int, image_size: int = 64, max_batch_size: int = spec.LARGE_NUM_SAMPLES
    ) -> None:
        self.action_dim = int(action_dim)
        self.image_size = int(image_size)
        self.max_batch_size = int(max_batch_size)

    def predict(self, context_frames: Tensor, actions: Tensor, **unused: Any) -> Tensor:
        """``(B, 10, 3, H, W)`` copies of ``context_frames[:, -1]`` as float32.

        The actions and the ``generator`` and ``grad`` keywords of the model interface are
        accepted and ignored.
        """
        last = context_frames[:, -1:].float()  # (B, 1, 3, H, W)
        return last.expand(-1, self.num_future, -1, -1, -1).contiguous()  # (B, T, 3, H, W)
