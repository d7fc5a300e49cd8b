"""Chi-square quantiles: the filters' innovation gates and the ANEES bounds."""

from __future__ import annotations

from scipy.special import chdtri


def chi2_quantile(probability: float, dof: float) -> float:
    """The value a chi-square variable of `dof` degrees of freedom stays below with `probability`:
    `scipy.stats.chi2.ppf`, through `scipy.special.chdtri`, which spares the command line the
    import of scipy.stats (about 0.5 s)."""
    return float(chdtri(dof, 1.0 - probability))
