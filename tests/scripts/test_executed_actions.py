"""``benchmarks.studies.executed_actions``: executed actions of runs against a reference run."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
MODULE = "benchmarks.studies.executed_actions"


def _run(folder: Path, trials: dict[tuple[str, int, int], np.ndarray], error_key=None) -> Path:
    folder.mkdir()
    lines = []
    for (task, instance, seed), actions in trials.items():
        record = {"task": task, "instance": instance, "seed": seed, "success": False,
                  "actions": actions.tolist()}
        if (task, instance, seed) == error_key:
            record = {**record, "error": "worker died", "actions": []}
        lines.append(json.dumps(record))
    (folder / "trials.jsonl").write_text("\n".join(lines) + "\n")
    return folder


def test_rows_measure_how_far_each_run_moved_from_the_reference(tmp_path):
    rng = np.random.default_rng(0)
    keys = [("robodesk/push_red", i, s) for i in range(2) for s in (0, 1)]
    base = {k: np.vstack([np.zeros((1, 5)), rng.uniform(-0.2, 0.2, (14, 5))]) for k in keys}
    near = {k: a + 0.004 * (i + 1) for i, (k, a) in enumerate(base.items())}
    far = {k: np.vstack([a[:1], np.full((14, 5), 0.5)]) for k, a in base.items()}
    ref = _run(tmp_path / "ref", base)
    # One of the near run's trials is an error record: it is not paired.
    near_dir = _run(tmp_path / "near", near, error_key=keys[0])
    far_dir = _run(tmp_path / "far", far)
    out = tmp_path / "rows.json"
    proc = subprocess.run(
        [sys.executable, "-m", MODULE, "--reference", str(ref), str(near_dir), str(far_dir),
         "--json", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=120, check=True,
    )
    rows = json.loads(out.read_text())
    assert rows[str(ref)]["max_abs_diff_max"] == 0
    r = rows[str(near_dir)]
    assert r["paired_trials"] == 3
    assert r["max_abs_diff_median"] == pytest.approx(0.012)
    assert r["max_abs_diff_max"] == pytest.approx(0.016)
    f = rows[str(far_dir)]
    assert f["mean_abs_xyz"] == pytest.approx(0.5)
    assert f["net_xyz_command"] == pytest.approx(np.linalg.norm([7.0, 7.0, 7.0]))
    assert "| near | 3 | 0.0120 | 0.0160 |" in proc.stdout


def test_a_run_without_paired_trials_is_refused_in_one_line(tmp_path):
    ref = _run(tmp_path / "ref", {("robodesk/push_red", 0, 0): np.zeros((15, 5))})
    other = _run(tmp_path / "other", {("robodesk/push_red", 1, 0): np.zeros((15, 5))})
    proc = subprocess.run([sys.executable, "-m", MODULE, "--reference", str(ref), str(other)],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert "no trial of this run has the same task, instance and seed" in proc.stderr
    assert "Traceback" not in proc.stderr
