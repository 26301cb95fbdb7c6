"""The numbers that fix the benchmark (``SPEC.md`` §4-§6), defined once.

Every module that needs one of these imports it from here; a test
(``tests/test_spec_constants.py``) fails when one of their literals is written again elsewhere.
This module imports nothing, so every stage may use it.
"""

from __future__ import annotations

# ---------------------------------------------------------------------------------- §4 trials

#: Context frames the benchmark gives a model.
NUM_CONTEXT = 2
#: Frames a model predicts per call: the planning horizon.
NUM_FUTURE = 10
#: Control steps per trial; the first executes the zero action.
NUM_CONTROL_STEPS = 15
#: Control runs (seeds) per task instance in the SPEC protocol.
MIN_SEEDS = 3

# --------------------------------------------------------------------------------- §5 planner

#: Planner samples per step: 200, and 800 for the two hardest RoboDesk tasks (``open_slide``,
#: ``open_drawer``); which task uses which is :attr:`vp2.envs.tasks.Task.num_samples`.
NUM_SAMPLES = 200
LARGE_NUM_SAMPLES = 800
#: MPPI iterations per control step.
NUM_ITERATIONS = 1
#: MPPI inverse temperature γ.
GAMMA = 0.05
#: Correlation coefficient β of the correlated-noise sampler.
BETA = 0.5
#: Per-action-dimension noise scales σ. RoboDesk actions are (dx, dy, dz, wrist, gripper);
#: tabletop actions are (dx, dy, dz, gripper), and the gripper is never sampled there.
SIGMA: dict[str, tuple[float, ...]] = {
    "robodesk": (0.5, 0.5, 0.5, 0.1, 0.1),
    "tabletop": (0.5, 0.5, 0.5, 0.0),
}
#: Ensembles: the weight λ of the members' disagreement ``max_i ‖Iⁱ − mean‖₁`` that is
#: subtracted from a randomly chosen member's score.
ENSEMBLE_DISAGREEMENT_WEIGHT = 0.01

# ----------------------------------------------------------------------------------- §6 costs

#: Tabletop cost: ``TABLETOP_PIXEL_WEIGHT * pixel SSE``.
TABLETOP_PIXEL_WEIGHT = 1.0
#: RoboDesk cost: ``PIXEL_WEIGHT * pixel SSE + CLASSIFIER_WEIGHT * (- sum of success logits)``.
ROBODESK_PIXEL_WEIGHT = 0.5
ROBODESK_CLASSIFIER_WEIGHT = 10.0

# ------------------------------------------------------------------------------ not the SPEC

#: Planner samples of the learned model in ``vp2 main`` (10 minutes on a 2-core CPU); the
#: main job says it deviates from :data:`NUM_SAMPLES`.
MAIN_JOB_NUM_SAMPLES = 50
