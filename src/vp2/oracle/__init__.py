"""The shipped oracle: the simulator oracle's success rates that normalise a run's scores.

==================  ==========================================================================
shipped.py          the asset ``vp2/assets/oracle.json`` (ShippedOracle, load_shipped_oracle)
                    and how every command normalises a run by it (summarize_run)
tables.py           one table of the asset (the oracle at one planner budget), and which
                    table normalises each task of a run (match_tables)
build.py            ``vp2 ship-oracle``: oracle runs -> ``results/oracle`` -> the asset
replay.py           replaying an oracle trial record against the simulator (replay_record)
==================  ==========================================================================

It reads runs through :mod:`vp2.run` (records, run directories, the run's config); the runner
(:mod:`vp2.benchmark.runner`), the main job and the report normalise through
:func:`summarize_run`. The names below are imported on first use, so importing one module of
the package does not load the others (or torch).

See ``docs/evaluation.md``.
"""

from vp2.utils.lazy import lazy_exports

#: Where the names of the package live (imported on first use).
_LAZY_MODULES: dict[str, list[str]] = {
    "vp2.oracle.build": ["build_asset", "build_table", "write_oracle_asset", "write_table"],
    "vp2.oracle.replay": ["Replay", "replay_record"],
    "vp2.oracle.shipped": [
        "ShippedOracle", "default_asset_path", "is_oracle_config", "load_shipped_oracle",
        "summarize_run",
    ],
    "vp2.oracle.tables": ["OracleMatch", "OracleTable", "OracleTask", "match_tables"],
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _LAZY_MODULES)
