"""Experiments around vp2: measurements, studies and the model comparison (index: README.md).

Every script runs from the repository root as a module, e.g.
``python -m benchmarks.speed.bench_planner --help``.
"""
