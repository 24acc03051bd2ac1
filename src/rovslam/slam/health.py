"""Health checks of the EKF's covariance: the cheap one after every change, the full O(N^3) one on demand.

Both raise :class:`rovslam.errors.FilterInconsistencyError` with a loud message when the
covariance is no longer a valid one (a negative variance or eigenvalue beyond rounding, an
asymmetry, a NaN).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rovslam.errors import FilterInconsistencyError

__all__ = ["ConsistencyReport", "check_blocks", "check_consistency"]

# Relative tolerance of the covariance health checks (negative variance, asymmetry).
PSD_RTOL = 1e-9


@dataclass(frozen=True)
class ConsistencyReport:
    """Figures of a full covariance check (:meth:`rovslam.slam.ekf.EkfSlam.check_consistency`)."""

    state_dim: int
    max_asymmetry: float  # max |P - P^T| before symmetrisation
    min_eigenvalue: float
    max_eigenvalue: float
    min_diagonal: float


def check_blocks(p: np.ndarray, n: int, k: int, where: str) -> None:
    """Cheap check of ``P[:n, :n]``: every variance >= 0, the vehicle's and state row k's 2x2 blocks PSD."""
    diag = np.diagonal(p)[:n]
    dmax = float(diag.max())
    tol = PSD_RTOL * max(dmax, 1e-30)
    dmin = float(diag.min())
    if not (math.isfinite(dmin) and math.isfinite(dmax)) or dmin < -tol:
        j = int(np.argmin(diag)) if math.isfinite(dmin) else int(np.flatnonzero(~np.isfinite(diag))[0])
        raise FilterInconsistencyError(
            f"FILTER INCONSISTENT after {where}: variance of state entry {j} is {diag[j]:.3e} "
            f"(negative or not finite); the covariance is no longer positive semi-definite. "
            "Check the noise figures (Q, pixel sigma) and the inputs fed to the filter."
        )
    for r in (0, k):  # the vehicle's and the landmark's 2x2 blocks
        b = p[r : r + 2, r : r + 2]
        (b00, b01), (b10, b11) = b.tolist()  # Python floats: the same products, without NumPy scalars
        if b00 * b11 - b01 * b10 < -tol * tol:
            raise FilterInconsistencyError(
                f"FILTER INCONSISTENT after {where}: the 2x2 covariance block at state {r} "
                f"is not positive semi-definite: {b.tolist()}"
            )


def check_consistency(p_full: np.ndarray, n: int, repair: bool = True) -> ConsistencyReport:
    """Full O(N^3) check of ``P[:n, :n]``: symmetry and positive semi-definiteness.

    Symmetrises it in place when ``repair``. Raises :class:`FilterInconsistencyError` when an
    eigenvalue is negative beyond rounding or an entry is not finite.
    """
    p = p_full[:n, :n]
    if not np.all(np.isfinite(p)):
        raise FilterInconsistencyError(
            "FILTER INCONSISTENT: the covariance holds NaN or infinite entries; a bad input reached the filter"
        )
    asym = float(np.max(np.abs(p - p.T))) if n else 0.0
    sym = 0.5 * (p + p.T)
    if repair:
        p[...] = sym
    eig = np.linalg.eigvalsh(sym)
    emin, emax = float(eig[0]), float(eig[-1])
    report = ConsistencyReport(n, asym, emin, emax, float(np.min(np.diagonal(sym))))
    tol = PSD_RTOL * max(emax, 1e-30) * max(n, 1)
    if emin < -tol or asym > tol:
        raise FilterInconsistencyError(
            f"FILTER INCONSISTENT: covariance of dimension {n} has min eigenvalue {emin:.3e} "
            f"(max {emax:.3e}) and asymmetry {asym:.3e}; it is no longer a valid covariance. "
            f"Check the noise figures and the inputs fed to the filter. {report}"
        )
    return report
