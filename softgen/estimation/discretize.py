"""Continuous-to-discrete conversion of the linear models that feed the UIO.

The thesis turns every continuous model ``Ẋ = A_c X + B_c U`` into the
discrete form of eq. 5.1, ``X_{k+1} = A X_k + B U_k``, with Euler's rule
(proofs of Theorems 1-4): ``A = I + T A_c``, ``B = T B_c``. The printed observer
matrices of those theorems only come out with this choice, so it is the
default here. The exact zero-order-hold discretisation is offered as well,

.. math::

    \\exp\\left(T \\begin{pmatrix} A_c & B_c \\\\ 0 & 0 \\end{pmatrix}\\right)
    = \\begin{pmatrix} A & B \\\\ 0 & I \\end{pmatrix},

which is what ``scipy.signal.cont2discrete(..., method="zoh")`` computes.
The output equation ``Y = C X + D U`` is the same in both time domains.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from softgen.core.errors import ShapeError

__all__ = ["discretize", "METHODS"]

#: Discretisation rules understood by :func:`discretize`.
METHODS = ("euler", "zoh")


def as_matrix(name: str, value) -> np.ndarray:
    """``value`` as a finite, real, 2-D float array, or one clear error naming ``name``.

    Shared with :mod:`softgen.estimation.uio`. Nothing is reshaped: scalars and
    1-D vectors are rejected rather than guessed into a row or a column.
    """
    try:
        arr = np.array(value)
    except (TypeError, ValueError):
        raise ShapeError(f"{name}: expected a 2-D array, got a ragged nested sequence") from None
    if np.iscomplexobj(arr):
        raise ValueError(f"{name}: expected a real matrix, got complex entries")
    try:
        arr = arr.astype(float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected numbers, got entries of type {arr.dtype}") from None
    if arr.ndim != 2:
        hint = "scalars are not broadcast" if arr.ndim == 0 else "nothing is reshaped"
        raise ShapeError(f"{name}: expected a 2-D array, got {arr.ndim}-D with shape {arr.shape} "
                         f"({hint}; pass e.g. [[0]], [[0], [1]] or [[1, 0]])")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: expected finite entries, got NaN or inf")
    return arr


def discretize(Ac, Bc, dt, *, method: str = "euler") -> tuple[np.ndarray, np.ndarray]:
    """Discretise ``Ẋ = A_c X + B_c U`` with sample time ``dt``.

    Parameters
    ----------
    Ac : array_like, shape (n, n)
        Continuous state matrix.
    Bc : array_like, shape (n, m)
        Continuous input matrix.
    dt : float
        Sample time ``T`` (finite, > 0).
    method : {"euler", "zoh"}, optional
        ``"euler"`` (default, the thesis's choice in the proofs of Theorems 1-4):
        ``A = I + T A_c``, ``B = T B_c``. ``"zoh"``: exact zero-order hold,
        ``A = e^{T A_c}``, ``B = ∫_0^T e^{s A_c} ds B_c``, from the matrix
        exponential of the augmented matrix ``[[A_c, B_c], [0, 0]]``.

    Returns
    -------
    A : numpy.ndarray, shape (n, n)
    B : numpy.ndarray, shape (n, m)
        The matrices of eq. 5.1.

    Raises
    ------
    ShapeError
        ``Ac`` is not a square 2-D array, or ``Bc`` is not 2-D with ``n`` rows.
    ValueError
        ``dt`` is not a finite positive number, ``method`` is unknown, or an
        entry is complex or not finite.

    Examples
    --------
    >>> A, B = discretize([[0, 1], [0, 0]], [[0], [1]], 0.1)
    >>> A
    array([[1. , 0.1],
           [0. , 1. ]])
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.integer, np.floating)):
        raise ValueError(f"dt: expected a finite number > 0, got {dt!r} "
                         f"({type(dt).__name__})")
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a finite number > 0, got {dt!r}")
    dt = float(dt)
    Ac = as_matrix("Ac", Ac)
    Bc = as_matrix("Bc", Bc)
    n = Ac.shape[0]
    if Ac.shape != (n, n) or n == 0:
        raise ShapeError(f"Ac: expected a non-empty square matrix (n, n), got shape {Ac.shape}")
    if Bc.shape[0] != n:
        raise ShapeError(f"Bc: expected {n} rows to match Ac {Ac.shape}, got shape {Bc.shape}")
    m = Bc.shape[1]
    if method == "euler":
        return np.eye(n) + dt * Ac, dt * Bc
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = Ac
    aug[:n, n:] = Bc
    phi = scipy.linalg.expm(dt * aug)
    return phi[:n, :n].copy(), phi[:n, n:].copy()
