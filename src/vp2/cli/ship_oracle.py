"""``vp2 ship-oracle``: the shipped oracle (the default normaliser), from simulator-oracle runs
through the trial records under ``results/oracle`` to ``vp2/assets/oracle.json``."""

from __future__ import annotations

import argparse
from pathlib import Path

from vp2.oracle.build import (
    META_FILE,
    RESULTS_DIR,
    asset_text,
    build_asset,
    build_table,
    read_table,
    write_oracle_asset,
    write_table,
)
from vp2.oracle.merge import merge_tables
from vp2.oracle.shipped import (
    ASSET_FILE,
    default_asset_path,
    load_shipped_oracle,
    parse_asset,
)
from vp2.run.run_dir import TRIALS_FILE

NAME = "ship-oracle"
HELP = "build the shipped oracle's tables (the default normaliser) from simulator-oracle runs"
DESCRIPTION = (
    "With RUN_DIRs (finished simulator-oracle runs at one planner budget): writes the table's "
    f"evidence to RESULTS/NAME ({META_FILE}, {TRIALS_FILE}), then rebuilds vp2/assets/{ASSET_FILE} "
    "from every table under RESULTS. Without RUN_DIRs (or with --from-results): only rebuilds "
    "the asset from RESULTS, byte for byte the same from the same files. vp2 run, main and "
    "report normalise each task by the table of the run's planner samples "
    "(docs/evaluation.md, 'The shipped oracle')."
)


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 ship-oracle`` arguments to ``p`` (a sub-parser) and returns it."""
    p.add_argument(
        "run_dirs",
        nargs="*",
        type=Path,
        metavar="RUN_DIR",
        help="simulator-oracle run directories (vp2 run --model simulator) of one planner "
        "budget, finished, no errors",
    )
    p.add_argument(
        "--table",
        default=None,
        metavar="NAME",
        help="the table the runs make (its folder under RESULTS; default: 'spec' at the "
        "SPEC's 200/800 samples, 'samples-N' at N)",
    )
    p.add_argument(
        "--results",
        type=Path,
        default=RESULTS_DIR,
        metavar="DIR",
        help=f"the folder of tables (default: {RESULTS_DIR}, run from the repository root)",
    )
    p.add_argument(
        "--from-results",
        nargs="?",
        type=Path,
        const=RESULTS_DIR,
        default=None,
        metavar="DIR",
        help=f"rebuild the asset from DIR's tables alone (default DIR: {RESULTS_DIR}); no RUN_DIRs",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="PATH",
        help=f"the asset file to write (default: the package's vp2/assets/{ASSET_FILE})",
    )
    p.add_argument(
        "--update",
        action="store_true",
        help="with RUN_DIRs: replace only the runs' tasks in the existing table NAME, keeping "
        "its other tasks' records (which must still match the task suite)",
    )
    p.add_argument(
        "--tasks",
        nargs="+",
        default=None,
        metavar="TASK",
        help="with RUN_DIRs: only these task categories (or environments) of the runs, each "
        "finished, e.g. the categories a long run has done (default: all the runs planned; "
        "every planned trial of a shipped task must have finished)",
    )
    p.add_argument("--note", default="", metavar="TEXT", help="free text stored with the table")
    p.add_argument(
        "--date",
        default=None,
        metavar="YYYY-MM-DD",
        help="when the oracle ran (default: the date its last trial finished)",
    )
    p.add_argument(
        "--check",
        action="store_true",
        help="write nothing; exit 1 if the asset differs from what RESULTS gives",
    )
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 ship-oracle`` from parsed arguments."""
    if args.from_results is not None and args.run_dirs:
        raise ValueError("--from-results rebuilds the asset from results alone: give no RUN_DIR")
    if args.check and args.run_dirs:
        raise ValueError("--check compares the asset with the results: give no RUN_DIR")
    results = args.from_results if args.from_results is not None else args.results
    if args.update and not args.run_dirs:
        raise ValueError("--update replaces tasks of a table with RUN_DIRs: give the runs")
    if args.run_dirs:
        meta, trials = build_table(args.run_dirs, name=args.table, note=args.note, date=args.date,
                                   tasks=args.tasks)
        if args.update:
            folder = Path(results) / str(meta["name"])
            if not (folder / META_FILE).is_file():
                raise ValueError(
                    f"--update: no table {meta['name']!r} under {results} to update; drop "
                    "--update to make it from the runs alone"
                )
            old_meta, old_trials = read_table(folder)
            meta, trials = merge_tables(old_meta, old_trials, meta, trials)
        folder = write_table(meta, trials, results)
        print(f"wrote {folder} ({len(trials)} trials)")
    elif args.table or args.note or args.date or args.tasks:
        raise ValueError("--table, --note, --date and --tasks describe a table made from RUN_DIRs")
    asset = build_asset(results)
    out = args.out if args.out is not None else default_asset_path()
    if args.check:
        same = out.is_file() and out.read_text() == asset_text(asset)
        print(f"{out} {'matches' if same else 'differs from'} {results}")
        return 0 if same else 1
    out = write_oracle_asset(asset, out)
    oracle = load_shipped_oracle(out) or parse_asset(asset, out)
    for table in oracle.tables:
        print(table.describe())
        for name, t in table.tasks.items():
            print(
                f"  {name:34s} {100 * t.rate:5.1f}%  ({t.successes}/{t.trials} trials, "
                f"{len(t.instances)} instances, {t.num_samples} samples)"
            )
    print(f"wrote {out}")
    return 0
