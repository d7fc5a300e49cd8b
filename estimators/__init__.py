"""Estimators behind one interface: `Estimator.update(sample) -> Estimate | None`."""

from estimators.base import Estimate, Estimator

__all__ = ["Estimate", "Estimator"]
