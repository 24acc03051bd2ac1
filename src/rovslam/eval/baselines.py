"""Baselines a SLAM result is compared with: the simplest seabed odometry a user could write.

Frame-to-frame phase correlation (``cv2.phaseCorrelate`` on Hann-windowed grey images) gives
the image shift of the seabed between consecutive frames; scaled to metres by the altitude and
turned into the world by the compass heading, it integrates into a path. No tokens, no
landmarks, no filter, no tilt compensation. (An optional high pass exists; on the simulated
dives it changed nothing in clear water and made turbid dives worse, so it is off.)

Convention (DESIGN.md): the seabed moves opposite to the vehicle. ``cv2.phaseCorrelate(a, b)``
returns the shift ``(du, dv)`` in pixels of the content of ``b`` relative to ``a`` (u right,
v down). With ``m = cy - v`` (forward) and ``n = u - cx`` (starboard) a seabed point moves by
``[dm, dn] = [-dv, du]``, and by equation (3) (camera turned by ``gamma`` about its axis) the
vehicle moved by ``[d_fwd, d_stbd] = -(Z/f) R(gamma) [dm, dn] = (Z/f) R(gamma) [dv, -du]`` in
the body frame, then ``R(psi)`` of that in the world.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from rovslam.camera import step_mean_heading_rad
from rovslam.errors import InvalidArgumentError, ResultsFormatError


def grey_for_correlation(image: np.ndarray, highpass_sigma_px: float = 0.0, max_width_px: int = 640) -> np.ndarray:
    """``(H, W, 3) uint8`` RGB (or ``(H, W)``) -> ``(h, w) float32`` grey, high-passed, at most ``max_width_px`` wide.

    The optional high pass (image minus its Gaussian blur of ``highpass_sigma_px``; 0, the
    default, for none) removes vignetting and lamp falloff, which stay put in the image. Wide
    images (HD) are shrunk by an integer factor so one correlation stays cheap;
    :func:`frame_shifts_px` scales the shift back.
    """
    import cv2

    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    elif img.ndim == 2:
        grey = img
    else:
        raise InvalidArgumentError(f"expected an (H, W, 3) RGB or (H, W) grey image, got shape {img.shape}")
    grey = grey.astype(np.float32)
    factor = _shrink_factor(grey.shape[1], max_width_px)
    if factor > 1:
        grey = cv2.resize(grey, (grey.shape[1] // factor, grey.shape[0] // factor), interpolation=cv2.INTER_AREA)
    if highpass_sigma_px > 0:
        grey = grey - cv2.GaussianBlur(grey, (0, 0), highpass_sigma_px / factor)
    return grey


def _shrink_factor(width_px: int, max_width_px: int) -> int:
    return max(1, -(-int(width_px) // int(max_width_px))) if max_width_px > 0 else 1


def frame_shifts_px(
    images: Iterable[np.ndarray | None], highpass_sigma_px: float = 0.0, max_width_px: int = 640
) -> np.ndarray:
    """Seabed image shift ``(du, dv)`` in full-resolution pixels from each frame to the next. ``(N-1, 2)``.

    ``images`` yields ``(H, W, 3) uint8`` frames in time order; ``None`` (an unreadable
    frame) gives NaN shifts to and from it.
    """
    import cv2

    shifts: list[tuple[float, float]] = []
    prev = None
    window = None
    factor = 1
    first = True
    for image in images:
        cur = None
        if image is not None:
            factor = _shrink_factor(np.asarray(image).shape[1], max_width_px)
            cur = grey_for_correlation(image, highpass_sigma_px, max_width_px)
            if window is None or window.shape != cur.shape:
                window = cv2.createHanningWindow((cur.shape[1], cur.shape[0]), cv2.CV_32F)
        if not first:
            if prev is None or cur is None or prev.shape != cur.shape:
                shifts.append((np.nan, np.nan))
            else:
                (du, dv), _ = cv2.phaseCorrelate(prev, cur, window)
                shifts.append((du * factor, dv * factor))
        first = False
        prev = cur
    return np.asarray(shifts, dtype=np.float64).reshape(-1, 2)


def integrate_shifts(
    shifts_px: np.ndarray,
    altitude_m: np.ndarray,
    heading_rad: np.ndarray,
    fx_px: float,
    fy_px: float,
    yaw_offset_rad: float = 0.0,
) -> np.ndarray:
    """World path ``(N, 2)`` from the origin, given ``(N-1, 2)`` image shifts and ``(N,)`` altitude and heading.

    The step from frame k-1 to k uses the mean of the two frames' altitudes and headings (the
    heading mean taken on the circle). A step whose shift, altitude or heading is NaN (an
    unreadable frame, no compass) moves nothing.
    """
    shifts = np.asarray(shifts_px, dtype=np.float64)
    alt = np.asarray(altitude_m, dtype=np.float64)
    psi = np.asarray(heading_rad, dtype=np.float64)
    n = len(alt)
    if shifts.shape != (max(n - 1, 0), 2) or psi.shape != (n,):
        raise InvalidArgumentError(
            f"need (N-1, 2) shifts and (N,) altitudes and headings, got {shifts.shape}, {alt.shape}, {psi.shape}"
        )
    if n == 0:
        return np.zeros((0, 2))
    z_m = 0.5 * (alt[:-1] + alt[1:])
    psi_mid = step_mean_heading_rad(psi)
    du, dv = shifts[:, 0], shifts[:, 1]
    # Body-frame vehicle displacement before the camera's own turn gamma: (Z/f) [dv, -du].
    a = z_m * dv / fy_px
    b = -z_m * du / fx_px
    cg, sg = np.cos(yaw_offset_rad), np.sin(yaw_offset_rad)
    fwd, stbd = cg * a - sg * b, sg * a + cg * b
    c, s = np.cos(psi_mid), np.sin(psi_mid)
    step = np.column_stack([c * fwd - s * stbd, s * fwd + c * stbd])
    step[~np.all(np.isfinite(step), axis=1)] = 0.0
    return np.vstack([np.zeros((1, 2)), np.cumsum(step, axis=0)])


def phase_correlation_path(
    sequence,
    altitude_m: np.ndarray | None = None,
    t_s: np.ndarray | None = None,
    highpass_sigma_px: float = 0.0,
    max_width_px: int = 640,
) -> np.ndarray:
    """Frame-to-frame phase-correlation odometry of an opened sequence. ``(N, 2)`` metres from the origin.

    ``sequence`` is a :class:`rovslam.io.sequence.Sequence`. ``t_s`` (N,) picks the frames to
    use (those a run processed, matched by time); default all. ``altitude_m`` (N,) is the
    altitude the run measured at those frames (``trajectory.csv`` ``altitude_m``); NaN or
    missing values fall back to the sequence's fixed altitude (``[vehicle] altitude_m``), then
    to the nearest measured one. The heading is ``frames.csv`` ``heading_rad``.
    """
    rows = list(sequence.rows)
    keep = np.arange(len(rows))
    if t_s is not None:
        from rovslam.eval.align import align_by_time

        keep = align_by_time(np.asarray(t_s, dtype=np.float64), np.array([r.t_s for r in rows]))
    n = len(keep)
    alt = _altitudes(n, altitude_m, sequence.info.fixed_altitude_m, sequence.folder)
    heading = np.array([rows[i].heading_rad for i in keep], dtype=np.float64)
    wanted = set(int(i) for i in keep)

    if np.any(np.diff(keep) <= 0):
        raise InvalidArgumentError("t_s must be strictly increasing, as the rows of trajectory.csv are")

    def images():  # streamed: the frames of a run are in time order
        for frame in sequence.frames(stop=int(keep.max()) + 1 if n else 0):
            if frame.index in wanted:
                yield frame.image

    cam = sequence.info.camera
    shifts = frame_shifts_px(images(), highpass_sigma_px, max_width_px)
    return integrate_shifts(shifts, alt, heading, cam.fx_px, cam.fy_px, cam.yaw_offset_rad)


def _altitudes(n: int, altitude_m: np.ndarray | None, fixed_m: float | None, where) -> np.ndarray:
    alt = np.full(n, np.nan) if altitude_m is None else np.asarray(altitude_m, dtype=np.float64).copy()
    if alt.shape != (n,):
        raise InvalidArgumentError(f"altitude_m must have one value per frame ({n}), got shape {alt.shape}")
    bad = ~(np.isfinite(alt) & (alt > 0))
    if bad.any() and fixed_m is not None:
        alt[bad] = fixed_m
    elif bad.any():
        good = np.nonzero(~bad)[0]
        if len(good) == 0:
            raise ResultsFormatError(
                f"{where}: no altitude for the phase-correlation baseline: the run measured none and "
                "sequence.toml has no [vehicle] altitude_m; add one."
            )
        alt[bad] = np.interp(np.nonzero(bad)[0], good, alt[good])
    return alt
