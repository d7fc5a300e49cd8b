"""Estimators behind one interface: `Estimator.update(sample) -> Estimate | None`."""

import testbed  # noqa: F401 - first: it chooses numba's cache folder before numba is imported
from estimators.base import Estimate, Estimator

__all__ = ["Estimate", "Estimator"]
