"""``vp2 diagnose``: whether a model can plan, in minutes; and the run's pre-check.

==================  ==========================================================================
model.py            DiagnoseConfig, diagnose_model, write_report, and the run's pre-check
                    (precheck_model, the one function the runner calls)
measures.py         the measurements, one function each (action conditioning, planning
                    agreement, ...)
verdicts.py         the thresholds and the verdicts on those measurements
score.py            the predicted control score: the measurements mapped to a success rate
partial.py          a diagnosis's partial file, so that an interrupted diagnosis resumes
==================  ==========================================================================

It builds on :mod:`vp2.run` (the run's config, ``--model`` resolution, the control trial); the
runner (:mod:`vp2.benchmark.runner`) calls :func:`precheck_model` before a run's first trial.
The names below are imported on first use, so importing one module of the package does not load
the others (or torch).

See ``docs/diagnose.md``.
"""

from vp2.utils.lazy import lazy_exports

#: Where the names of the package live (imported on first use).
_LAZY_MODULES: dict[str, list[str]] = {
    "vp2.diagnose.model": [
        "DiagnoseConfig", "diagnose_model", "format_report", "measure_conditioning",
        "precheck_model", "write_report",
    ],
    "vp2.diagnose.partial": ["PartialDiagnosis"],
    "vp2.diagnose.score": ["load_predictor", "predicted_score"],
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _LAZY_MODULES)
