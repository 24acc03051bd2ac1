"""Vehicle motion model (1) as pure functions: ``[x, y](k+1) = [x, y](k) + R(psi) [u, v] dt``.

Used by the filter's prediction, by the dead reckoning the pipeline reports beside it, and
by the landmark search (where the vehicle is expected before this frame's speed is known).
"""

from __future__ import annotations

import numpy as np

from rovslam.camera import drot2, rot2

__all__ = ["motion_step_m", "motion_jacobians"]


def motion_step_m(speed_mps: np.ndarray, heading_rad: float, dt_s: float) -> np.ndarray:
    """(1) without noise: (2,) body speed [u, v] over ``dt_s`` at heading psi -> (2,) world displacement, metres."""
    return rot2(heading_rad) @ np.asarray(speed_mps, dtype=np.float64) * dt_s


def motion_jacobians(speed_mps: np.ndarray, heading_rad: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of (1)'s displacement: ``(G (2, 2) = d/d[u, v] = R dt, j (2,) = d/dpsi = dR/dpsi [u, v] dt)``."""
    return rot2(heading_rad) * dt_s, drot2(heading_rad) @ np.asarray(speed_mps, dtype=np.float64) * dt_s
