"""Global motion between two frames from point features, with its covariance (large motions).

For motions too large for the speed tokens' search windows (a third of the image, a turn of
tens of degrees, a change of altitude), the seabed's motion between two frames is found from
keypoints: ORB on CLAHE-equalised grey images, matched by Lowe's ratio test,
then a RANSAC similarity (``cv2.estimateAffinePartial2D``) refined by least squares on its
inliers. The similarity maps a pixel ``(u, v)`` of the first frame to the second::

    [u', v'] = [[a, -b], [b, a]] [u, v] + [tx, ty],   a = s cos(theta), b = s sin(theta)

(``s`` the scale, ``theta`` the rotation, image axes u right, v down, pixels of the full
resolution). Its covariance is the inliers' residual variance times the inverse of the normal
matrix of their design (``sigma^2 (J^T J)^-1`` over ``[a, b, tx, ty]``; the residual never
below a floor for the keypoints' own localisation error), inflated by the inliers per occupied
cell of a 10 x 10 grid: neighbouring keypoints share their errors, the residuals alone would
make the covariance several times too small (measured on the photomosaic pairs of the tests). When there is no reliable motion (too few matches or
inliers, a low inlier share, a degenerate spread of inliers, an implausible scale) the result
says so (``ok=False``) with the reason: "none" rather than a wrong motion.

Pure: images in, numbers out. The numbers are in full-resolution pixels whatever the working
size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rovslam.camera import Camera, undistort_pixels
from rovslam.errors import InvalidArgumentError


@dataclass(frozen=True)
class FeatureConfig:
    """How the feature motion is measured; every value is checked at construction.

    ``max_features``: keypoints per image (ORB; OpenCV 5 has no AKAZE in its main module). ``ratio``:
    Lowe's ratio of the best to the second-best match distance. ``ransac_threshold_px``: the
    RANSAC inlier distance at the working size. ``max_width_px``: images wider are shrunk by an
    integer factor first. ``min_inliers`` / ``min_inlier_share``: below either, no motion.
    ``scale_range``: the plausible scales between two frames. ``min_sigma_px``: the floor of the
    residual standard deviation (keypoint localisation at the working size).
    """

    max_features: int = 3000
    ratio: float = 0.8
    ransac_threshold_px: float = 2.0
    max_width_px: int = 800
    min_inliers: int = 15
    min_inlier_share: float = 0.25
    scale_range: tuple[float, float] = (0.67, 1.5)
    min_sigma_px: float = 0.3

    def __post_init__(self) -> None:
        checks = (
            ("max_features", self.max_features >= 10),
            ("ratio", 0.0 < self.ratio < 1.0),
            ("ransac_threshold_px", self.ransac_threshold_px > 0.0),
            ("max_width_px", self.max_width_px >= 64),
            ("min_inliers", self.min_inliers >= 3),
            ("min_inlier_share", 0.0 <= self.min_inlier_share <= 1.0),
            ("scale_range", 0.0 < self.scale_range[0] < 1.0 < self.scale_range[1]),
            ("min_sigma_px", self.min_sigma_px >= 0.0),
        )
        bad = [name for name, ok in checks if not ok]
        if bad:
            raise InvalidArgumentError(f"FeatureConfig: out of range: {', '.join(bad)} (see its docstring)")


@dataclass(frozen=True)
class FeatureMotion:
    """The similarity from the first frame to the second, or none (``ok=False``) with the reason.

    ``params``: ``(4,)`` ``[a, b, tx_px, ty_px]``; ``cov_params``: ``(4, 4)`` their covariance
    (``a``, ``b`` dimensionless, ``t`` in px). ``matches``: ratio-test matches; ``inliers``:
    RANSAC inliers; ``inlier_share`` = inliers / matches. When ``ok`` is False the parameters
    are NaN.
    """

    ok: bool
    reason: str
    params: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))
    cov_params: np.ndarray = field(default_factory=lambda: np.full((4, 4), np.nan))
    matches: int = 0
    inliers: int = 0
    inlier_share: float = 0.0
    residual_sigma_px: float = float("nan")

    @property
    def translation_px(self) -> np.ndarray:
        """``(2,)`` ``[tx, ty]`` px: where the first frame's pixel (0, 0) goes, minus (0, 0)."""
        return self.params[2:4].copy()

    @property
    def cov_translation_px2(self) -> np.ndarray:
        """``(2, 2)`` px^2: covariance of :attr:`translation_px`."""
        return self.cov_params[2:4, 2:4].copy()

    @property
    def rotation_rad(self) -> float:
        """The rotation theta (radians, from u towards v: clockwise as seen on screen)."""
        return math.atan2(float(self.params[1]), float(self.params[0]))

    @property
    def scale(self) -> float:
        """The scale s (> 1: the second frame sees the seabed larger, closer)."""
        return math.hypot(float(self.params[0]), float(self.params[1]))

    @property
    def rotation_sigma_rad(self) -> float:
        """Standard deviation of :attr:`rotation_rad` (first order)."""
        return _polar_sigmas(self.params, self.cov_params)[1]

    @property
    def scale_sigma(self) -> float:
        """Standard deviation of :attr:`scale` (first order)."""
        return _polar_sigmas(self.params, self.cov_params)[0]

    def matrix(self) -> np.ndarray:
        """``(2, 3)`` the similarity as an affine matrix (first frame's pixels -> second's)."""
        a, b, tx, ty = (float(x) for x in self.params)
        return np.array([[a, -b, tx], [b, a, ty]])


def point_motion_px(motion: FeatureMotion, point_uv_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the first frame's pixel ``point_uv_px`` ``(2,)`` moved: ``(2,)`` displacement px and ``(2, 2)`` px^2.

    The displacement is ``A p - p``; its covariance ``J C J^T`` with ``J = [[u, -v, 1, 0], [v, u, 0, 1]]``.
    NaN when the motion is none.
    """
    p = np.asarray(point_uv_px, dtype=np.float64)
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        raise InvalidArgumentError(f"point_uv_px must be a finite (2,) pixel, got {p!r}")
    jac = _design(p[None, :])
    moved = jac @ motion.params
    return moved - p, jac @ motion.cov_params @ jac.T


def feature_motion(
    first: np.ndarray, second: np.ndarray, config: FeatureConfig = FeatureConfig(), camera: Camera | None = None
) -> FeatureMotion:
    """The seabed's similarity motion from ``first`` to ``second`` ``(H, W, 3) uint8`` RGB or ``(H, W)`` grey.

    Both images must have the same shape. Returns a :class:`FeatureMotion` in full-resolution
    pixels; ``ok=False`` with the reason when no motion is reliable. ``camera``: when given, the
    keypoints are freed of its lens distortion before the fit (ideal pinhole pixels; a barrel
    lens otherwise shrinks the fitted motion by several per cent).
    """
    a = _check_image(first, "first")
    b = _check_image(second, "second")
    if a.shape != b.shape:
        raise InvalidArgumentError(f"the two images differ in shape: {a.shape} and {b.shape}")
    if camera is not None and camera.shape != a.shape[:2]:
        raise InvalidArgumentError(f"the images are {a.shape[1]}x{a.shape[0]} px, the camera's {camera.shape[::-1]}")
    factor = max(1, -(-a.shape[1] // config.max_width_px))
    pts_a, pts_b, n_matches = match_keypoints(_prepare(a, factor), _prepare(b, factor), config)
    if n_matches < config.min_inliers:
        return FeatureMotion(False, f"too few feature matches ({n_matches} < {config.min_inliers})", matches=n_matches)
    full_a, full_b = (pts_a + 0.5) * factor - 0.5, (pts_b + 0.5) * factor - 0.5  # INTER_AREA's pixel centres
    if camera is not None:
        full_a, full_b = undistort_pixels(camera, full_a), undistort_pixels(camera, full_b)
    return fit_similarity(full_a, full_b, config, scale_px=float(factor))


def match_keypoints(
    grey_a: np.ndarray, grey_b: np.ndarray, config: FeatureConfig = FeatureConfig()
) -> tuple[np.ndarray, np.ndarray, int]:
    """Keypoints of two ``(h, w) uint8`` images matched by the ratio test: ``(M, 2)``, ``(M, 2)`` px and ``M``."""
    import cv2

    detector = cv2.ORB_create(nfeatures=config.max_features, fastThreshold=5, edgeThreshold=15, patchSize=31)  # type: ignore[attr-defined]  # cv2 5 stubs lack it
    kp_a, des_a = detector.detectAndCompute(grey_a, None)
    kp_b, des_b = detector.detectAndCompute(grey_b, None)
    empty = np.zeros((0, 2))
    if des_a is None or des_b is None or len(kp_a) < 2 or len(kp_b) < 2:
        return empty, empty, 0
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    pairs = matcher.knnMatch(des_a, des_b, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < config.ratio * p[1].distance]
    if not good:
        return empty, empty, 0
    pts_a = np.array([kp_a[m.queryIdx].pt for m in good], dtype=np.float64)
    pts_b = np.array([kp_b[m.trainIdx].pt for m in good], dtype=np.float64)
    return pts_a, pts_b, len(good)


def fit_similarity(
    pts_a_px: np.ndarray, pts_b_px: np.ndarray, config: FeatureConfig = FeatureConfig(), scale_px: float = 1.0
) -> FeatureMotion:
    """RANSAC similarity from ``(M, 2)`` points to ``(M, 2)`` points, refined on its inliers, with its covariance.

    ``scale_px``: the pixels of the points per working pixel of the keypoints (the RANSAC
    threshold and the residual floor of ``config`` are scaled by it). ``ok=False`` with the reason when the inliers are too few, too small a share, spread
    degenerately (nearly collinear) or give an implausible scale.
    """
    import cv2

    pa = np.asarray(pts_a_px, dtype=np.float64)
    pb = np.asarray(pts_b_px, dtype=np.float64)
    if pa.ndim != 2 or pa.shape[1:] != (2,) or pa.shape != pb.shape:
        raise InvalidArgumentError(f"need two (M, 2) point arrays of the same shape, got {pa.shape} and {pb.shape}")
    m = len(pa)
    if m < max(3, config.min_inliers):
        return FeatureMotion(False, f"too few feature matches ({m} < {config.min_inliers})", matches=m)
    _, mask = cv2.estimateAffinePartial2D(
        pa,
        pb,
        method=cv2.RANSAC,
        ransacReprojThreshold=config.ransac_threshold_px * scale_px,
        maxIters=4000,
        confidence=0.999,
    )
    inl = np.zeros(m, bool) if mask is None else mask.ravel().astype(bool)
    n_in = int(inl.sum())
    share = n_in / m
    if n_in < config.min_inliers:
        return FeatureMotion(False, f"too few inliers ({n_in} of {m} matches)", matches=m, inliers=n_in)
    if share < config.min_inlier_share:
        reason = f"inlier share {share:.2f} below {config.min_inlier_share:.2f} ({n_in} of {m} matches)"
        return FeatureMotion(False, reason, matches=m, inliers=n_in, inlier_share=share)
    return _refine(pa[inl], pb[inl], config, m, scale_px)


def _refine(pa: np.ndarray, pb: np.ndarray, config: FeatureConfig, m: int, scale_px: float) -> FeatureMotion:
    """Least squares on the inliers (full-resolution px) and ``sigma^2 (J^T J)^-1``; checks the result."""
    n_in = len(pa)
    share = n_in / m
    jac = _design(pa)
    normal = jac.T @ jac
    spread = np.linalg.eigvalsh(np.cov(pa.T)) if n_in > 2 else np.zeros(2)
    if spread[0] < 1e-3 * max(spread[1], 1e-12) or spread[1] <= 0.0:
        reason = f"degenerate inliers: {n_in} nearly collinear or coincident points"
        return FeatureMotion(False, reason, matches=m, inliers=n_in, inlier_share=share)
    params = np.linalg.solve(normal, jac.T @ pb.reshape(-1))
    resid = jac @ params - pb.reshape(-1)
    sigma2 = float(resid @ resid) / max(2 * n_in - 4, 1)
    sigma2 = max(sigma2, (config.min_sigma_px * scale_px) ** 2)
    # Neighbouring keypoints share their errors (the same texture, the same interpolation): the
    # covariance counts one independent point per occupied cell of a 10 x 10 grid over the inliers.
    cov = sigma2 * np.linalg.inv(normal) * (n_in / _independent_points(pa))
    motion = FeatureMotion(True, "", params, 0.5 * (cov + cov.T), m, n_in, share, math.sqrt(sigma2))
    lo, hi = config.scale_range
    if not lo <= motion.scale <= hi:
        reason = f"implausible scale {motion.scale:.3f} between two frames (outside {lo}..{hi})"
        return FeatureMotion(False, reason, matches=m, inliers=n_in, inlier_share=share)
    return motion


def compose(later: FeatureMotion, earlier: FeatureMotion) -> np.ndarray:
    """``(2, 3)`` the similarity of ``earlier`` followed by ``later`` (first frame of ``earlier`` -> last of ``later``)."""
    m1 = np.vstack([earlier.matrix(), [0.0, 0.0, 1.0]])
    m2 = np.vstack([later.matrix(), [0.0, 0.0, 1.0]])
    return (m2 @ m1)[:2]


def similarity_design(points_px: np.ndarray) -> np.ndarray:
    """``(2N, 4)``: where ``(N, 2)`` points go is this times ``[a, b, tx, ty]`` (rows ``[u, -v, 1, 0]``, ``[v, u, 0, 1]``)."""
    return _design(np.asarray(points_px, dtype=np.float64).reshape(-1, 2))


def _design(points_px: np.ndarray) -> np.ndarray:
    """``(2N, 4)`` the design of ``[a, b, tx, ty]`` for ``(N, 2)`` points: rows ``[u, -v, 1, 0]``, ``[v, u, 0, 1]``."""
    n = len(points_px)
    jac = np.zeros((2 * n, 4))
    u, v = points_px[:, 0], points_px[:, 1]
    jac[0::2, 0], jac[0::2, 1], jac[0::2, 2] = u, -v, 1.0
    jac[1::2, 0], jac[1::2, 1], jac[1::2, 3] = v, u, 1.0
    return jac


def _independent_points(points_px: np.ndarray, cells: int = 10) -> int:
    """How many cells of a ``cells x cells`` grid over the points' bounding box hold at least one of ``(N, 2)`` points."""
    lo = points_px.min(axis=0)
    span = np.maximum(points_px.max(axis=0) - lo, 1e-9)
    idx = np.minimum((cells * (points_px - lo) / span).astype(int), cells - 1)
    return max(1, len(np.unique(idx[:, 0] * cells + idx[:, 1])))


def _polar_sigmas(params: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """First-order standard deviations of the scale and rotation from ``[a, b]``'s covariance."""
    a, b = float(params[0]), float(params[1])
    s = math.hypot(a, b)
    if not s > 0.0:
        return float("nan"), float("nan")
    j = np.array([[a / s, b / s], [-b / s**2, a / s**2]])
    c = j @ cov[:2, :2] @ j.T
    return math.sqrt(max(c[0, 0], 0.0)), math.sqrt(max(c[1, 1], 0.0))


def _check_image(image: np.ndarray, name: str) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8 or not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)):
        raise InvalidArgumentError(
            f"{name} image: expected (H, W, 3) RGB or (H, W) grey uint8, got shape {img.shape} {img.dtype}"
        )
    if min(img.shape[:2]) < 32:
        raise InvalidArgumentError(f"{name} image: {img.shape[1]}x{img.shape[0]} px is too small (32 px at least)")
    return img


def _prepare(image: np.ndarray, factor: int) -> np.ndarray:
    """``(h, w) uint8``: grey, shrunk by ``factor``, equalised (CLAHE) so low-contrast seabeds give keypoints."""
    import cv2

    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    if factor > 1:
        grey = cv2.resize(grey, (grey.shape[1] // factor, grey.shape[0] // factor), interpolation=cv2.INTER_AREA)
    return cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8)).apply(grey)
