"""benchmarks/studies/action_conditioning.py prints the measure of `vp2 diagnose`."""

from __future__ import annotations

import re
from pathlib import Path

import torch
from benchmarks.studies import action_conditioning

from tests.models.synthetic import write_moving_square_dataset
from vp2.diagnose.model import measure_conditioning
from vp2.run.model_spec import resolve_model

SHIFT = "tests.diagnose.test_model:ShiftModel"


def test_the_study_prints_the_ratio_and_clips_of_the_diagnosis(tmp_path, capsys):
    data = write_moving_square_dataset(tmp_path / "squares", size=64, action_dim=4)
    action_conditioning.main(["--model", SHIFT, "--data", str(data), "--env", "tabletop",
                              "--clips", "8", "--samples", "1"])
    out = capsys.readouterr().out
    model = resolve_model(SHIFT, {}, env="tabletop", action_dim=4, device="cpu")
    r = measure_conditioning(model, Path(data), 8, 1, 0, torch.device("cpu"))
    assert r["clips"] == 8 and r["ratio"] > 1.5  # the shift model uses its actions
    assert out.startswith(f"8 held-out clips of {data}")
    assert f"| ratio shuffled / true | {r['ratio']:.3f} | {r['moving']['ratio']:.3f} |" in out
    assert re.search(rf"\| clips where true < shuffled \| {r['wins']}/8 \|", out)
