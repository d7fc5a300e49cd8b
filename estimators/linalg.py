"""Fixed-size linear algebra for the filters' hot paths, where numpy's per-call overhead (about
1 us) dominates the arithmetic of 3-vectors and 3x3 matrices."""

from __future__ import annotations

import numpy as np
from numba import njit

from testbed.model.kinematics import fused_multiply_add


def skew(v) -> np.ndarray:
    """[v]x, the cross-product matrix: skew(a) @ b == cross(a, b)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross for two 3-vectors, ten times cheaper."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def inverse3(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix by cofactors: a quarter of the cost of np.linalg.inv at this size."""
    (a, b, c), (d, e, f), (g, h, i) = matrix.tolist()
    cofactors = (e * i - f * h, c * h - b * i, b * f - c * e,
                 f * g - d * i, a * i - c * g, c * d - a * f,
                 d * h - e * g, b * g - a * h, a * e - b * d)
    determinant = a * cofactors[0] + b * cofactors[3] + c * cofactors[6]
    return np.array(cofactors).reshape(3, 3) / determinant


# Compiled code's `@` on 3x3 operands is a BLAS call of about 0.4 us. The OpenBLAS kernel numpy and
# numba run on this CPU sums each element of such a product as an FMA chain over k from zero, which
# these reproduce bit for bit (test_3x3_products_equal_numpy_and_numba_bit_for_bit checks it: a
# different BLAS kernel would change the filters' last bits, not their results' meaning).
@njit(cache=True)
def product3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b for 3x3 matrices (a new array), as `@` computes it (compiled code only)."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            total = fused_multiply_add(a[i, 0], b[0, j], 0.0)
            total = fused_multiply_add(a[i, 1], b[1, j], total)
            out[i, j] = fused_multiply_add(a[i, 2], b[2, j], total)
    return out


@njit(cache=True)
def transposed_product3(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """a @ v for a transposed 3x3 matrix `a` (Fortran order, as `m.T`) and a 3-vector (a new
    array), as `@` computes it (compiled code only). OpenBLAS sums a C-order matrix's rows in
    another order: not for those."""
    out = np.empty(3)
    for i in range(3):
        total = fused_multiply_add(a[i, 0], v[0], 0.0)
        total = fused_multiply_add(a[i, 1], v[1], total)
        out[i] = fused_multiply_add(a[i, 2], v[2], total)
    return out


# [v]x = [[0, -z, y], [z, 0, -x], [-y, x, 0]]: positions, sources and signs of its six entries.
_SKEW_ROWS = np.array([0, 0, 1, 1, 2, 2])
_SKEW_COLUMNS = np.array([1, 2, 0, 2, 0, 1])
_SKEW_SOURCE = [2, 1, 2, 0, 1, 0]
_SKEW_SIGN = np.array([-1.0, 1.0, 1.0, -1.0, -1.0, 1.0])


def _skew_indices(count: int) -> tuple[np.ndarray, np.ndarray]:
    rows = (3 * np.arange(count)[:, None] + _SKEW_ROWS).ravel()
    return rows, np.tile(_SKEW_COLUMNS, count)


_SKEW_INDICES = {count: _skew_indices(count) for count in range(1, 7)}


def stacked_skew(vectors: np.ndarray) -> np.ndarray:
    """(3n, 3): the cross-product matrices of n row vectors, stacked."""
    count = len(vectors)
    rows, columns = _SKEW_INDICES[count] if count in _SKEW_INDICES else _skew_indices(count)
    out = np.zeros((3 * count, 3))
    out[rows, columns] = (vectors[:, _SKEW_SOURCE] * _SKEW_SIGN).ravel()
    return out
