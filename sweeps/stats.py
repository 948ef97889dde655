"""Summary statistics over seeds: the interquartile mean (IQM) with a bootstrap
confidence interval, as Agarwal et al. (2021, "Deep RL at the edge of the
statistical precipice") recommend for few runs.

Each comparison row is one robot/task, so its only stratum is the seeds and the
stratified bootstrap is the plain one over seeds; numbers of different tasks
(different measures and units) are never pooled.
"""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

N_RESAMPLES = 9999  # scipy.stats.bootstrap's default


def iqm(values: Iterable[float | None]) -> float:
    """The mean of the middle half (``scipy.stats.trim_mean(values, 0.25)``; with fewer
    than four values nothing is cut: their mean); NaN for none. None and NaN are left out."""
    from scipy.stats import trim_mean

    x = _finite(values)
    return float(trim_mean(x, 0.25)) if len(x) else math.nan


def iqm_ci(values: Iterable[float | None], confidence: float = 0.95, n_resamples: int = N_RESAMPLES,
           seed: int = 0) -> tuple[float, float, float]:
    """``(iqm, low, high)``: the IQM of ``values`` (one per seed) and its percentile bootstrap
    confidence interval at ``confidence``, from ``n_resamples`` resamples of the seeds drawn
    with a generator seeded by ``seed`` (the same values give the same interval).

    One value has no spread to resample: its interval is ``(nan, nan)``. Values all equal
    give the degenerate interval ``(v, v)``. No values: all three NaN. None and NaN are left out.
    """
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1); got {confidence}")
    x = _finite(values)
    centre = iqm(x)
    if len(x) < 2:
        return centre, math.nan, math.nan
    if np.all(x == x[0]):  # nothing to resample; scipy would warn about a degenerate sample
        return centre, float(x[0]), float(x[0])
    from scipy.stats import bootstrap, trim_mean

    result = bootstrap((x,), lambda s, axis=-1: trim_mean(s, 0.25, axis=axis), vectorized=True,
                       n_resamples=int(n_resamples), confidence_level=confidence, method="percentile",
                       random_state=np.random.default_rng(seed))
    low, high = result.confidence_interval
    return centre, float(low), float(high)


def format_iqm_ci(centre: float, low: float, high: float, n: int) -> str:
    """``8.6 [4.7, 12.3]``; ``4.7 [1 seed: no CI]``; ``-`` without values (``n``: how many)."""
    if n == 0 or math.isnan(centre):
        return "-"
    if n == 1:
        return f"{centre:.3g} [1 seed: no CI]"
    return f"{centre:.3g} [{low:.3g}, {high:.3g}]"


def _finite(values: Iterable[float | None]) -> np.ndarray:
    x = np.array([v for v in values if v is not None], dtype=float)
    return x[np.isfinite(x)]
