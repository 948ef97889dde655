"""Summary statistics over seeds: the interquartile mean (IQM) with a bootstrap
confidence interval, as Agarwal et al. (2021, "Deep RL at the edge of the
statistical precipice") recommend for few runs.

Each comparison row is one robot/task, so its only stratum is the seeds and the
stratified bootstrap is the plain one over seeds; numbers of different tasks
(different measures and units) are never pooled.

Both are written here in numpy, in place of ``scipy.stats.trim_mean`` and
``scipy.stats.bootstrap(method="percentile")``: importing ``scipy.stats`` took 0.49 s of
``compare.py``'s 1.47 s CPU (``python -X importtime``), and a comparison's table is
meant to answer in under a second. ``tests/test_stats.py`` holds them to scipy's: the
IQM exactly, the interval's ends within a few percent of its width (the resamples differ).
"""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

N_RESAMPLES = 9999  # scipy.stats.bootstrap's default


def iqm(values: Iterable[float | None]) -> float:
    """The mean of the middle half (``scipy.stats.trim_mean(values, 0.25)``; with fewer
    than four values nothing is cut: their mean); NaN for none. None and NaN are left out."""
    x = _finite(values)
    return float(_trim_mean(x[None, :])[0]) if len(x) else math.nan


def _trim_mean(samples: np.ndarray) -> np.ndarray:
    """Each row's mean after cutting ``int(0.25 * n)`` values from each end (scipy's rule)."""
    n = samples.shape[-1]
    cut = int(0.25 * n)
    return np.sort(samples, axis=-1)[:, cut:n - cut].mean(axis=-1)


def iqm_ci(values: Iterable[float | None], confidence: float = 0.95, n_resamples: int = N_RESAMPLES,
           seed: int = 0) -> tuple[float, float, float]:
    """``(iqm, low, high)``: the IQM of ``values`` (one per seed) and its percentile bootstrap
    confidence interval at ``confidence``, from ``n_resamples`` resamples of the seeds drawn
    with a generator seeded by ``seed`` (the same values give the same interval, in any
    order: they are sorted before they are resampled).

    One value has no spread to resample: its interval is ``(nan, nan)``. Values all equal
    give the degenerate interval ``(v, v)``. No values: all three NaN. None and NaN are left out.
    """
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1); got {confidence}")
    x = np.sort(_finite(values))  # the seeds' order is not the interval's
    centre = iqm(x)
    if len(x) < 2:
        return centre, math.nan, math.nan
    if np.all(x == x[0]):  # nothing to resample; scipy would warn about a degenerate sample
        return centre, float(x[0]), float(x[0])
    rng = np.random.default_rng(seed)
    resampled = _trim_mean(x[rng.integers(0, len(x), size=(int(n_resamples), len(x)))])
    tail = (1 - confidence) / 2 * 100
    low, high = np.percentile(resampled, [tail, 100 - tail])
    return centre, float(low), float(high)


FEW_SEEDS = 5  # below this many seeds a bootstrap interval is only a rough one: the table says so


def format_iqm_ci(centre: float, low: float, high: float, n: int) -> str:
    """``8.6 [4.7, 12.3]``; ``2.5 [1, 4; 2 seeds: rough]`` below :data:`FEW_SEEDS` (a
    bootstrap over 2-4 values spans little more than their range); ``4.7 [1 seed: no CI]``;
    ``-`` without values (``n``: how many)."""
    if n == 0 or math.isnan(centre):
        return "-"
    if n == 1:
        return f"{centre:.3g} [1 seed: no CI]"
    rough = f"; {n} seeds: rough" if n < FEW_SEEDS else ""
    return f"{centre:.3g} [{low:.3g}, {high:.3g}{rough}]"


def _finite(values: Iterable[float | None]) -> np.ndarray:
    x = np.array([v for v in values if v is not None], dtype=float)
    return x[np.isfinite(x)]
