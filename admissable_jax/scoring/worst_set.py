"""Is the worst set the worst? The gap between two sets' scores, and the episodes that would resolve it.

a_u is a mean over N episodes, so with small N the set of lowest a_u may be the worst by
chance. Where every set's episode i starts from one state (the audit's batched rollout:
common random numbers), the gap between two sets is judged episode by episode: the paired
differences carry no reset noise, so their interval is tighter than two independent samples'
wherever the sets' returns rise and fall together with the start state. Where the sets'
episodes start from different states (a
Gymnasium vector env's own resets), Welch's t over the two samples.

The samples that would tell two means apart (episodes per set here; seeds per mode when
plot compares adversarial with uniform training): the least n per group at which a
two-sided 5% t-test finds a gap of the size seen 80% of the time, at the spread seen,
n ≥ ((t_0.975 + t_0.8) · s / gap)², the t quantiles at the test's degrees of freedom (n − 1
paired; Welch–Satterthwaite's for two independent groups of n, between n − 1 and 2n − 2),
s the standard deviation of one paired difference, or √(s_1² + s_2²) for independent
samples. For large n this is the normal approximation, ((z_0.975 + z_0.8) · s / gap)²; for
a few seeds the t quantiles make it larger (finals 40, 60 against 8, 10: 2 seeds per mode
by the normal approximation, 4 by t).

NumPy and SciPy: the returns come from any scorer, one row of N per set.
"""

from __future__ import annotations

import math

import numpy as np

Z_SUM = 2.8016  # z_0.975 + z_0.8: a two-sided 5% test with 80% power, for large n


def t_half_width(samples: np.ndarray, axis: int = -1) -> float | np.ndarray:
    """Half-width of the 95% Student's t interval of the mean of ``samples`` along ``axis``
    (a float for one sample, else an array); NaN with fewer than 2 values."""
    from scipy import stats

    samples = np.asarray(samples, np.float64)
    n = samples.shape[axis]
    if n < 2:
        width = np.full(np.delete(samples.shape, axis), np.nan)
    else:
        width = stats.t.ppf(0.975, n - 1) * samples.std(axis=axis, ddof=1) / math.sqrt(n)
    return float(width) if np.ndim(width) == 0 else width


def gap_above(low: np.ndarray, high: np.ndarray, paired: bool) -> tuple[float, float]:
    """(mean of ``high`` − mean of ``low``, its 95% interval's half-width): paired episode by
    episode, or Welch's t."""
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    gap = float(high.mean() - low.mean())
    if paired:
        return gap, t_half_width(high - low)
    from scipy import stats

    low_var, high_var = low.var(ddof=1) / len(low), high.var(ddof=1) / len(high)
    standard_error = math.sqrt(low_var + high_var)
    if standard_error == 0:
        return gap, 0.0
    freedom = (low_var + high_var) ** 2 / (low_var ** 2 / (len(low) - 1) + high_var ** 2 / (len(high) - 1))
    return gap, float(stats.t.ppf(0.975, freedom) * standard_error)


def samples_to_separate(low: np.ndarray, high: np.ndarray, paired: bool) -> int | None:
    """Samples per group (at least 2) that would tell ``high``'s mean from ``low``'s at the gap
    and spread seen (module docstring); None where the gap is not positive or nothing varies."""
    from scipy import stats

    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    gap = high.mean() - low.mean()
    variances = (low.var(ddof=1), high.var(ddof=1))
    spread = (high - low).std(ddof=1) if paired else math.sqrt(sum(variances))
    if gap <= 0 or spread == 0:
        return None
    ratio = (spread / gap) ** 2
    # Welch–Satterthwaite's degrees of freedom for two groups of n: (n − 1) · this.
    welch_share = 1.0 if paired else sum(variances) ** 2 / (variances[0] ** 2 + variances[1] ** 2)

    def needed(n: int) -> float:  # ((t_0.975 + t_0.8) · s / gap)² at n's degrees of freedom
        freedom = (n - 1) * welch_share
        return (stats.t.ppf(0.975, freedom) + stats.t.ppf(0.8, freedom)) ** 2 * ratio

    n = max(2, math.ceil(Z_SUM ** 2 * ratio))  # the normal approximation: t's n is never smaller
    while n < needed(n):
        n += 1
    return n
