"""The vehicle-side API: feed frames one at a time, get the estimate and the next command back.

Example (a real vehicle; ``grab()`` and ``send()`` are the vehicle's own)::

    from rovslam.io.camera_file import read_camera_file
    from rovslam.io.sequence import Frame
    from rovslam.nav import Goal, Navigator

    info = read_camera_file("camera.toml").info
    nav = Navigator(info, [Goal("rock", np.array([0.4, -0.2])), Goal("back to landmark 0", None, landmark_id=0)])
    k = 0
    while not nav.done:
        t_s, image, heading_rad, sonar_m = grab()
        step = nav.step(Frame(k, t_s, image, heading_rad, sonar_m))
        send(step.command.surge_mps, step.command.sway_mps, step.command.yaw_rate_radps)
        k += 1

The command is the velocity through the water in the body frame (surge forward, sway to
starboard, m/s) and a yaw rate (rad/s), for the vehicle's own velocity loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovslam.config import RunConfig
from rovslam.core import Goal
from rovslam.nav.dynamics import Command
from rovslam.nav.estimate import DeadReckoningCovariance, check_estimator, nav_estimate
from rovslam.nav.guidance import GuidanceConfig, Mission, NavEstimate
from rovslam.pipeline import FrameResult, SlamPipeline

__all__ = ["NavStep", "Navigator"]


@dataclass(frozen=True)
class NavStep:
    """One frame's outcome: the pipeline's result, the estimate steered by, the command, the mission events."""

    result: FrameResult
    estimate: NavEstimate
    command: Command
    events: tuple  # Arrival / HoldEnd records of this frame
    phase: str  # "transit" | "hold" | "done"
    goal_index: int  # the goal being flown to after this frame (len(goals) when done)
    target_xy_m: np.ndarray | None  # (2,) the point steered to (None when done)
    current_mps: np.ndarray  # (2,) the controller's current estimate (world frame)


class Navigator:
    """The SLAM pipeline, an estimator (``slam`` or ``dead-reckoning``) and a :class:`Mission` in one object.

    ``info`` describes the camera and lasers (a :class:`rovslam.io.sequence.SequenceInfo`, e.g.
    from a camera file). Goals given by ``landmark_id`` are resolved from the online map at
    every frame. ``survey_until_s``: survey goals still ahead at that time are dropped.
    """

    def __init__(
        self,
        info,
        goals: list[Goal],
        estimator: str = "slam",
        config: RunConfig = RunConfig(),
        guidance: GuidanceConfig = GuidanceConfig(),
        survey_until_s: float | None = None,
    ) -> None:
        self.estimator = check_estimator(estimator)
        self.pipeline = SlamPipeline(info, config)
        self.mission = Mission(goals, guidance, self.landmark_xy_m, survey_until_s)
        self._dr = DeadReckoningCovariance()

    def landmark_xy_m(self, landmark_id: int) -> np.ndarray | None:
        """(2,) map position of a landmark, or None when the map does not hold it (yet)."""
        if int(landmark_id) not in self.pipeline.ekf.landmark_ids:
            return None
        return np.array(self.pipeline.ekf.landmark_xy_m(int(landmark_id)), dtype=np.float64)

    @property
    def done(self) -> bool:
        """Every goal reached (and held) or abandoned."""
        return self.mission.done

    def step(self, frame) -> NavStep:
        """Process one :class:`rovslam.io.sequence.Frame` (image, time, compass, sonar, attitude): the next command."""
        res = self.pipeline.process(frame)
        est = nav_estimate(res, self.estimator, self._dr)
        cmd, events = self.mission.update(est, res.dt_s)
        m = self.mission
        return NavStep(res, est, cmd, tuple(events), m.phase, m.p.index, m.target_xy_m, m.current_mps.copy())
