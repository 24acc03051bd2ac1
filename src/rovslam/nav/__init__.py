"""Navigation to points of interest: guidance and control fed by the per-frame estimate.

* :mod:`~rovslam.nav.guidance`: the way-point law, speed limits, arrival and station keeping, :class:`Mission`;
* :mod:`~rovslam.nav.estimate`: the estimate steered by, ``slam`` or ``dead-reckoning``;
* :mod:`~rovslam.nav.api`: :class:`Navigator`, frames in, estimate and command out (a real vehicle's API);
* :mod:`~rovslam.nav.dynamics`: a simple ROV (first-order surge, sway, yaw; a current; altitude control);
* :mod:`~rovslam.nav.closed_loop`: the closed loop in the simulator (frames rendered from the true state).
"""

from rovslam.core import Goal
from rovslam.nav.api import Navigator, NavStep
from rovslam.nav.dynamics import (
    Command,
    DynamicsParams,
    SimulatedVehicle,
    VehicleState,
    step_vehicle,
)
from rovslam.nav.estimate import ESTIMATORS, DeadReckoningCovariance, nav_estimate
from rovslam.nav.guidance import (
    Arrival,
    GuidanceConfig,
    HoldEnd,
    Mission,
    NavEstimate,
    arrival_state,
    body_command,
    ellipse_semi_major_m,
    saturate,
    waypoint_velocity,
)

__all__ = [
    "ESTIMATORS",
    "Arrival",
    "Command",
    "DeadReckoningCovariance",
    "DynamicsParams",
    "Goal",
    "GuidanceConfig",
    "HoldEnd",
    "Mission",
    "NavEstimate",
    "NavStep",
    "Navigator",
    "SimulatedVehicle",
    "VehicleState",
    "arrival_state",
    "body_command",
    "ellipse_semi_major_m",
    "nav_estimate",
    "saturate",
    "step_vehicle",
    "waypoint_velocity",
]
