"""Chi-square bounds for averaged NEES (normalised estimation error squared)."""

from __future__ import annotations

from scipy.stats import chi2


def mean_nees_bounds(*, dim: int, count: int) -> tuple[float, float]:
    """Two-sided 95% bounds of the mean of `count` NEES values of dimension `dim`."""
    dof = dim * count
    return float(chi2.ppf(0.025, dof)) / count, float(chi2.ppf(0.975, dof)) / count
