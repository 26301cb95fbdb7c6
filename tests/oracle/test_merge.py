"""Re-measuring some tasks of a committed oracle table (``vp2 ship-oracle --update``)."""

from __future__ import annotations

import pytest

from vp2.data.suite import SUITE_FORMAT, TaskSuite
from vp2.envs import TASK_NAMES
from vp2.oracle.build import RESULTS_DIR, read_table
from vp2.oracle.merge import merge_tables


def _tabletop_part(meta: dict) -> tuple[dict, list[dict]]:
    """A hand-made re-measurement of the tabletop on the shipped suite: instances #0-#1 of each
    category, seed 0, the first one solved."""
    suite = TaskSuite.load()
    trials = [
        {"task": t, "instance": i, "seed": 0, "instance_sha": suite.get(t, i).fingerprint,
         "success": i == 0, "first_success_step": 3 if i == 0 else None, "num_steps": 15,
         "num_samples": 50, "actions": [[0.0, 0.0, 0.0, 0.0]]}
        for t in TASK_NAMES if t.startswith("tabletop/") for i in (0, 1)
    ]  # fmt: skip
    new = {
        "name": meta["name"], "suite_format": SUITE_FORMAT, "date": "2026-11-29",
        "measured_by": "vp2 ship-oracle of 1 run(s) (tabletop-50)", "note": "the paper's scene",
        "vp2_version": "0.2.0", "settings": meta["settings"], "render": {"tabletop": "new"},
        "classifiers": {}, "commands": ["vp2 run --model simulator --tasks tabletop --out t"],
    }  # fmt: skip
    return new, trials


def _stale_table() -> tuple[dict, list[dict]]:
    """The committed `samples-50` table as it would be had its tabletop rows been measured on an
    earlier suite: their instance fingerprints are not the shipped suite's."""
    meta, trials = read_table(RESULTS_DIR / "samples-50")
    trials = [{**r, "instance_sha": "0" * 16} if r["task"].startswith("tabletop/") else r
              for r in trials]
    return meta, trials


def test_the_tabletop_rows_are_replaced_and_the_robodesk_rows_kept():
    old_meta, old_trials = _stale_table()
    new_meta, new_trials = _tabletop_part(old_meta)
    meta, trials = merge_tables(old_meta, old_trials, new_meta, new_trials)
    robodesk = [r for r in old_trials if r["task"].startswith("robodesk/")]
    assert len(robodesk) == 70 and len(trials) == 70 + 8
    assert [r for r in trials if r["task"].startswith("robodesk/")] == robodesk
    assert [r for r in trials if r["task"].startswith("tabletop/")] == sorted(
        new_trials, key=lambda r: (r["task"], r["instance"], r["seed"])
    )
    # The later of the two dates (the committed table's may be later than the hand-made part's).
    assert meta["suite_format"] == SUITE_FORMAT
    assert meta["date"] == max(old_meta["date"], "2026-11-29")
    assert meta["render"] == {"robodesk": old_meta["render"]["robodesk"], "tabletop": "new"}
    assert meta["classifiers"] == old_meta["classifiers"]  # all RoboDesk's, kept
    assert meta["vp2_version"] == "0.1.0, 0.2.0"
    # The old tabletop command goes, the RoboDesk ones stay, the new one is added.
    assert [c for c in meta["commands"] if "--tasks tabletop" in c] == new_meta["commands"]
    assert len(meta["commands"]) == 1 + sum("--tasks tabletop" not in c for c in old_meta["commands"])
    assert meta["note"].endswith(
        "Updated 2026-11-29 (tabletop/push_cylinder, tabletop/push_large_cube, "
        "tabletop/push_small_cube, tabletop/push_sphere): the paper's scene"
    )


def test_a_run_already_in_the_table_is_listed_once():
    # A long run ships category by category: each --update brings the same `vp2 run` command.
    old_meta, old_trials = read_table(RESULTS_DIR / "samples-50")
    robodesk = [c for c in old_meta["commands"] if "--tasks robodesk " in c]
    assert len(robodesk) == 1
    blue = [r for r in old_trials if r["task"] == "robodesk/push_blue"]
    by = "vp2 ship-oracle of 1 run(s) (robodesk-50)"
    old_meta = {**old_meta, "measured_by": f"first runs; robodesk/push_red then by {by}"}
    new_meta = {**old_meta, "note": "", "commands": robodesk, "measured_by": by}
    meta, trials = merge_tables(old_meta, old_trials, new_meta, blue)
    assert meta["commands"] == old_meta["commands"]
    # ... and the run's entry of `measured_by` gains the category instead of repeating
    assert meta["measured_by"] == f"first runs; robodesk/push_blue, robodesk/push_red then by {by}"
    other, _ = merge_tables(old_meta, old_trials, {**new_meta, "measured_by": "another"}, blue)
    assert other["measured_by"] == f"{old_meta['measured_by']}; robodesk/push_blue then by another"
    assert trials == sorted(old_trials, key=lambda r: (r["task"], r["instance"], r["seed"]))


def test_kept_records_on_changed_instances_and_other_settings_are_refused():
    old_meta, old_trials = _stale_table()
    new_meta, new_trials = _tabletop_part(old_meta)
    # Re-measuring push_red alone would keep the tabletop's records of another suite.
    red = [r for r in old_trials if r["task"] == "robodesk/push_red"]
    with pytest.raises(ValueError, match="keeps records of tabletop/push_cylinder, .* changed"):
        merge_tables(old_meta, old_trials, new_meta, red)
    other = {**new_meta, "settings": {**new_meta["settings"], "gamma": 0.5}}
    with pytest.raises(ValueError, match="update a table only with runs of its protocol"):
        merge_tables(old_meta, old_trials, other, new_trials)


def test_ship_oracle_update_command(tmp_path, capsys):
    from tests.oracle.fixtures import write_oracle_run
    from vp2 import cli

    results, out = tmp_path / "results", tmp_path / "oracle.json"
    first = write_oracle_run(tmp_path / "first")
    assert cli.main(["ship-oracle", str(first), "--results", str(results), "--out", str(out),
                     "--note", "first"]) == 0  # fmt: skip
    capsys.readouterr()
    # The same task measured again (one seed): the table keeps only the new records.
    again = write_oracle_run(tmp_path / "again", {(0, 0): False, (1, 0): True}, day=8)
    assert cli.main(["ship-oracle", str(again), "--update", "--results", str(results),
                     "--out", str(out), "--note", "again"]) == 0  # fmt: skip
    assert "wrote" in capsys.readouterr().out
    meta, trials = read_table(results / "spec")
    assert [(r["instance"], r["seed"], r["success"]) for r in trials] == [
        (0, 0, False),
        (1, 0, True),
    ]
    assert meta["date"] == "2026-11-28" and meta["note"].startswith("first Updated 2026-11-28")
    assert len(meta["commands"]) == 1 and meta["commands"][0].endswith("--out again")
    assert cli.main(["ship-oracle", "--update", "--results", str(results)]) == 2
    assert "give the runs" in capsys.readouterr().err
    assert cli.main(["ship-oracle", str(again), "--update", "--table", "other", "--results",
                     str(results), "--out", str(out)]) == 2  # fmt: skip
    assert "no table 'other'" in capsys.readouterr().err
