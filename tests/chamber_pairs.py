"""Frame pairs cut from the real chamber3 photomosaic with a known motion, and the loop's speed on them.

A pair is two 360x272 views of the mosaic (about 1 mm per mosaic pixel; the paper's camera at
Z = 1.31 m sees 1.2 mm per pixel): the second view's centre moved by ``shift_px`` (view pixels of
the first), turned by ``turn_deg`` (the vehicle's heading change, the compass reading it) and
zoomed by ``scale`` (the vehicle closer by that factor; the sonar altitude says so). Low-contrast
versions keep a quarter of the contrast and add seeded noise. The truth compared is the
quantity of :mod:`rovslam.eval.feature_reference`: where the first image's pixel now under the
principal point was, ``p - c`` (px of the first image).

``python tests/chamber_pairs.py`` prints the table of the pairs (``ROVSLAM_DATA`` set).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rovslam.camera import Camera
from rovslam.config import RunConfig
from rovslam.core import Frame, SequenceInfo
from rovslam.eval.feature_reference import token_motion_px

CAMERA = Camera(width_px=360, height_px=272, fx_px=1075.0, fy_px=1075.0, cx_px=179.5, cy_px=135.5)
Z_M = 1.31
DT_S = 0.2
MOSAIC_PX_PER_VIEW_PX = 1.2  # the view's pixel on the mosaic (about 1.2 mm)


@dataclass(frozen=True)
class PairSpec:
    """One pair: where in the mosaic, the motion of the view (first view's px), its turn and zoom."""

    name: str
    centre_px: tuple[float, float]  # the first view's centre on the mosaic
    shift_px: tuple[float, float]  # the second view's centre minus the first's, first view's pixels (u, v)
    turn_deg: float = 0.0
    scale: float = 1.0
    low_contrast: bool = False

    @property
    def overlap(self) -> float:
        """The share of the first view still seen in the second (translation only, a rough figure)."""
        return max(0.0, 1.0 - abs(self.shift_px[0]) / CAMERA.width_px) * max(
            0.0, 1.0 - abs(self.shift_px[1]) / CAMERA.height_px
        )


BASE_PAIRS = (
    PairSpec("70% right", (700.0, 700.0), (108.0, 0.0)),
    PairSpec("50% up", (1500.0, 800.0), (0.0, -136.0)),
    PairSpec("50% left, 10 deg, 3 %", (1100.0, 1500.0), (-180.0, 0.0), 10.0, 1.03),
    PairSpec("51% diagonal, -15 deg, 5 %", (1700.0, 1500.0), (100.0, 80.0), -15.0, 1.05),
    PairSpec("30% right, 5 deg, -3 %", (900.0, 1100.0), (250.0, 0.0), 5.0, 0.97),
    PairSpec("60% diagonal, 20 deg, 2 %", (1300.0, 1000.0), (60.0, -100.0), 20.0, 1.02),
)
PAIRS = BASE_PAIRS + tuple(
    PairSpec(p.name + ", low contrast", p.centre_px, p.shift_px, p.turn_deg, p.scale, True) for p in BASE_PAIRS
)


def render_view(mosaic: np.ndarray, centre_px: np.ndarray, heading_rad: float, zoom: float) -> np.ndarray:
    """``(272, 360, 3) uint8``: the view centred on ``centre_px`` of the mosaic, turned by the heading, zoomed.

    View pixel offset ``o`` from the principal point shows mosaic point
    ``centre + R(heading) o * MOSAIC_PX_PER_VIEW_PX / zoom`` (image-up = forward, heading from up towards right).
    """
    import cv2

    k = MOSAIC_PX_PER_VIEW_PX / zoom
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    lin = k * np.array([[c, -s], [s, c]])
    cxy = np.array([CAMERA.cx_px, CAMERA.cy_px])
    off = np.asarray(centre_px, dtype=np.float64) - lin @ cxy
    view_to_mosaic = np.hstack([lin, off[:, None]])
    return cv2.warpAffine(
        mosaic,
        view_to_mosaic,
        (CAMERA.width_px, CAMERA.height_px),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REFLECT,
    )


def _low_contrast(image: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = 128.0 + 0.25 * (image.astype(np.float64) - 128.0) + rng.normal(0.0, 1.5, image.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def pair_frames(mosaic: np.ndarray, spec: PairSpec, seed: int = 0) -> tuple[Frame, Frame, np.ndarray]:
    """The two frames of ``spec`` and the truth ``p - c`` ``(2,)`` px of the first image."""
    c0 = np.array(spec.centre_px)
    c1 = c0 + MOSAIC_PX_PER_VIEW_PX * np.array(spec.shift_px)
    psi1 = math.radians(spec.turn_deg)
    a = render_view(mosaic, c0, 0.0, 1.0)
    b = render_view(mosaic, c1, psi1, spec.scale)
    if spec.low_contrast:
        a, b = _low_contrast(a, seed), _low_contrast(b, seed + 1)
    f0 = Frame(index=0, t_s=0.0, image=a, heading_rad=0.0, sonar_altitude_m=Z_M)
    f1 = Frame(index=1, t_s=DT_S, image=b, heading_rad=psi1, sonar_altitude_m=Z_M / spec.scale)
    return f0, f1, np.array(spec.shift_px, dtype=np.float64)


@dataclass(frozen=True)
class PairResult:
    """What the loop measured on one pair: ``p - c`` px, its covariance px^2, and the errors."""

    spec: PairSpec
    truth_px: np.ndarray
    measured_px: np.ndarray
    cov_px2: np.ndarray
    speed_ok: bool
    inliers: int
    source: str = "tokens"  # what measured the speed (trajectory.csv's speed_source)

    @property
    def error_px(self) -> float:
        return float(np.linalg.norm(self.measured_px - self.truth_px))

    @property
    def relative(self) -> float:
        return self.error_px / float(np.linalg.norm(self.truth_px))

    @property
    def sigmas(self) -> float:
        """Mahalanobis distance of the truth under the measurement's covariance."""
        d = self.measured_px - self.truth_px
        try:
            return math.sqrt(max(float(d @ np.linalg.solve(self.cov_px2, d)), 0.0))
        except np.linalg.LinAlgError:
            return math.inf

    @property
    def passes(self) -> bool:
        """A measured speed within 10 % of the truth, or whose covariance holds it (99 %, 2 dof: 3.03 sigma)."""
        return self.speed_ok and (self.relative <= 0.10 or self.sigmas <= math.sqrt(9.21))


# The loop as it runs by default: the feature motion on (``[odometry] feature_assist_inliers = 3``).
ASSISTED = RunConfig()


def measure_pair(mosaic: np.ndarray, spec: PairSpec, config: RunConfig | None = None) -> PairResult:
    """Run the loop on the pair's two frames; the second frame's speed as ``p - c``."""
    from rovslam.pipeline import SlamPipeline

    f0, f1, truth = pair_frames(mosaic, spec)
    info = SequenceInfo(name="pair", camera=CAMERA, lasers=(), fixed_altitude_m=Z_M)
    pipe = SlamPipeline(info, config or ASSISTED)
    pipe.process(f0)
    r = pipe.process(f1)
    speed = np.array([r.surge_mps, r.sway_mps])
    px, cov = token_motion_px(speed, np.asarray(r.speed_cov_mps2), DT_S, Z_M, CAMERA)
    return PairResult(spec, truth, px, cov, bool(r.speed_ok), int(r.tokens_inliers), r.speed_source)


def load_mosaic(path: Path) -> np.ndarray:
    import cv2

    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FileNotFoundError(path)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def table(results: list[PairResult]) -> str:
    lines = [
        "| pair | overlap | truth p-c px | measured px | error px | error % | sigma x,y px | truth in sigmas | ok | inliers |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        sd = np.sqrt(np.maximum(np.diag(r.cov_px2), 0.0))
        lines.append(
            f"| {r.spec.name} | {r.spec.overlap:.0%} | ({r.truth_px[0]:.0f}, {r.truth_px[1]:.0f}) | "
            f"({r.measured_px[0]:.1f}, {r.measured_px[1]:.1f}) | {r.error_px:.1f} | {100 * r.relative:.1f} | "
            f"({sd[0]:.1f}, {sd[1]:.1f}) | {r.sigmas:.1f} | {'pass' if r.passes else 'FAIL'} "
            f"({'speed' if r.speed_ok else 'held'}) | {r.inliers} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    from rovslam import data

    mosaic = load_mosaic(data.path("chamber3", download=False) / "seabed.jpg")
    print(table([measure_pair(mosaic, p) for p in PAIRS]))
