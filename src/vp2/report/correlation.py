"""Rank correlation between a metric and control success across models (the study's test)."""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence


@dataclasses.dataclass
class Correlation:
    """Rank correlation between a metric and success across models, in one scope.

    Attributes:
        scope: Task, environment or all tasks (:data:`vp2.report.study.ALL_TASKS`).
        metric: :attr:`vp2.report.study.StudyMetric.key`.
        n: Models with both a metric value and a success rate.
        spearman: Spearman's ρ (``None``: undefined, see ``note``).
        spearman_p: Its two-sided p-value.
        kendall: Kendall's τ-b.
        kendall_p: Its two-sided p-value.
        note: Why a value is undefined, or ``""``.
    """

    scope: str
    metric: str
    n: int
    spearman: float | None
    spearman_p: float | None
    kendall: float | None
    kendall_p: float | None
    note: str = ""


def rank_correlation(
    x: Sequence[float], y: Sequence[float]
) -> tuple[float | None, float | None, float | None, float | None, str]:
    """Spearman's ρ and Kendall's τ-b of paired values, with p-values and a note.

    Ties get average ranks (ρ) and the τ-b correction. Fewer than 3 pairs, or a constant
    ``x`` or ``y``, give ``None`` values and a note saying why. Spearman's p-value is exact
    (a permutation test over all pairings) for up to :data:`EXACT_P_MAX_MODELS` models, and
    scipy's t approximation above; Kendall's is scipy's (exact for small samples without ties).

    Returns:
        ``(rho, rho_p, tau, tau_p, note)``.
    """
    from scipy import stats

    n = len(x)
    if n != len(y):
        raise ValueError(f"x and y differ in length ({n} vs {len(y)})")
    if n < 3:
        return None, None, None, None, f"{n} model(s); a rank correlation needs at least 3"
    if len(set(x)) == 1:
        return None, None, None, None, "the metric is the same for every model"
    if len(set(y)) == 1:
        return None, None, None, None, "success is the same for every model"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rho, rho_p = stats.spearmanr(x, y)
        tau, tau_p = stats.kendalltau(x, y)
    if n <= EXACT_P_MAX_MODELS:
        rho_p = _exact_spearman_p(x, y, float(rho))
    return float(rho), float(rho_p), float(tau), float(tau_p), ""


#: Up to this many models, Spearman's p-value is exact (all n! pairings); scipy's t
#: approximation gives p = 0 for a perfect ranking of 3 models, where the exact value is 1/3.
EXACT_P_MAX_MODELS = 8


def _exact_spearman_p(x: Sequence[float], y: Sequence[float], rho: float) -> float:
    """Two-sided permutation p-value of Spearman's ρ over every pairing of ``x`` and ``y``."""
    import itertools

    import numpy as np
    from scipy.stats import rankdata

    rx = rankdata(x) - (len(x) + 1) / 2
    ry = rankdata(y) - (len(y) + 1) / 2
    norm = math.sqrt(float(rx @ rx) * float(ry @ ry))
    perms = np.array(list(itertools.permutations(range(len(y)))))  # (n!, n)
    rhos = ry[perms] @ rx / norm  # (n!,)
    return float(np.mean(np.abs(rhos) >= abs(rho) - 1e-12))
