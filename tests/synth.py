"""Small seeded generator of synthetic seabed frames for the vision tests (no dependency on rovslam.sim).

* :func:`seabed_spectrum` makes a periodic, band-limited random texture (white noise filtered
  at a few Gaussian scales), kept as its 2-D spectrum so that any sub-pixel shift can be
  rendered exactly with a Fourier phase ramp.
* :func:`render_grey` renders the texture seen by a camera whose window starts at a
  sub-pixel offset: ``frame(u, v) = texture(u + offset_u, v + offset_v)``, so the image
  content moves by ``-(offset change)`` between frames.
* :func:`colourise` gives it a green/blue water tint, adds Gaussian noise and quantises to
  ``uint8`` RGB; :func:`draw_laser_spots` paints saturated red anti-aliased speckled discs.
* :func:`paper_camera` / :func:`paper_lasers`: the paper's rig (360x272, f = 1075 px, four
  pointers parallel to the optical axis at (+-0.05, +-0.05, 0) m).
* :func:`survey_measurements`: no images, the per-frame measurement records the SLAM back
  ends consume, from a true track (:func:`lawnmower_track`, :func:`crosshatch_track`) over
  a landmark field (:func:`landmark_field`), with seeded noise (:class:`SurveyNoise`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovslam.camera import Camera, LaserPointer, ground_to_pixels, rot2

DEFAULT_NOISE_SIGMA = 3.0  # 8-bit grey levels, per channel


def paper_camera() -> Camera:
    return Camera(width_px=360, height_px=272, fx_px=1075.0, fy_px=1075.0, cx_px=179.5, cy_px=135.5)


def paper_lasers() -> tuple[LaserPointer, ...]:
    return tuple(LaserPointer(origin_m=(sx * 0.05, sy * 0.05, 0.0)) for sx in (1, -1) for sy in (1, -1))


def seabed_spectrum(
    shape_hw: tuple[int, int] = (512, 512),
    seed: int = 0,
    sigmas_px: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0),
    weights: tuple[float, ...] = (0.6, 1.0, 1.0, 0.8),
    std_grey: float = 28.0,
) -> np.ndarray:
    """Spectrum ``(H, W) complex128`` of a periodic zero-mean texture with standard deviation ``std_grey``."""
    rng = np.random.default_rng(seed)
    h, w = shape_hw
    spec = np.fft.fft2(rng.standard_normal((h, w)))
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    f2 = fx * fx + fy * fy
    gain = np.zeros((h, w))
    for s, wt in zip(sigmas_px, weights, strict=True):
        # Each scale normalised to unit variance before weighting.
        g = np.exp(-2.0 * np.pi**2 * s * s * f2)
        gain += wt * g / np.sqrt(np.mean(g * g))
    spec = spec * gain
    spec[0, 0] = 0.0
    tex = np.fft.ifft2(spec).real
    return spec * (std_grey / tex.std())


def render_grey(
    spectrum: np.ndarray,
    offset_uv_px: tuple[float, float],
    shape_hw: tuple[int, int] = (272, 360),
    mean_grey: float = 110.0,
) -> np.ndarray:
    """``(H, W) float64`` frame with ``frame(u, v) = texture(u + offset_u, v + offset_v)`` (exact shift)."""
    th, tw = spectrum.shape
    ou, ov = offset_uv_px
    iu, iv = int(np.floor(ou)), int(np.floor(ov))
    fu, fv = ou - iu, ov - iv
    fy = np.fft.fftfreq(th)[:, None]
    fx = np.fft.fftfreq(tw)[None, :]
    ramp = np.exp(2j * np.pi * (fx * fu + fy * fv))
    tex = np.fft.ifft2(spectrum * ramp).real
    tex = np.roll(tex, (-iv, -iu), axis=(0, 1))
    h, w = shape_hw
    if h > th or w > tw:
        raise ValueError("texture smaller than the frame")
    return tex[:h, :w] + mean_grey


def colourise(
    grey: np.ndarray,
    seed: int = 0,
    noise_sigma: float = DEFAULT_NOISE_SIGMA,
    vignetting: float = 0.0,
) -> np.ndarray:
    """Water-tinted ``(H, W, 3) uint8`` RGB with Gaussian noise; ``vignetting`` in 0..1 darkens the corners."""
    rng = np.random.default_rng(seed)
    g = np.asarray(grey, dtype=np.float64)
    if vignetting:
        h, w = g.shape
        yy, xx = np.mgrid[0:h, 0:w]
        r2 = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (h / 2)) ** 2
        g = g * (1.0 - vignetting * r2 / 2.0)
    rgb = np.stack([0.35 * g + 10.0, 0.85 * g + 20.0, 0.70 * g + 30.0], axis=-1)
    if noise_sigma > 0:
        rgb = rgb + rng.normal(0.0, noise_sigma, rgb.shape)
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def laser_hit_pixels(
    camera: Camera,
    lasers: tuple[LaserPointer, ...],
    altitude_m: float,
    slope_fwd: float = 0.0,
    slope_stbd: float = 0.0,
) -> np.ndarray:
    """(L, 2) pixels where the laser rays hit the seabed plane ``z = Z + slope_fwd x + slope_stbd y`` (level camera)."""
    out = []
    for las in lasers:
        o = np.asarray(las.origin_m, float)
        d = las.unit_direction
        t = (altitude_m + slope_fwd * o[0] + slope_stbd * o[1] - o[2]) / (d[2] - slope_fwd * d[0] - slope_stbd * d[1])
        p = o + t * d
        out.append(ground_to_pixels(camera, p[None, :2], p[2])[0])
    return np.array(out)


def draw_laser_spots(rgb: np.ndarray, spots_uv_px: np.ndarray, seed: int = 0, radius_px: float = 2.5) -> np.ndarray:
    """Paint saturated red, speckled, anti-aliased discs at ``(L, 2)`` sub-pixel centres (copy)."""
    rng = np.random.default_rng(seed)
    out = rgb.astype(np.float64)
    h, w = rgb.shape[:2]
    ss = 4
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    for cu, cv in np.asarray(spots_uv_px, float):
        if not (np.isfinite(cu) and np.isfinite(cv)):
            continue
        r = radius_px + 3
        u0, u1 = max(0, int(cu - r)), min(w, int(cu + r) + 2)
        v0, v1 = max(0, int(cv - r)), min(h, int(cv + r) + 2)
        if u0 >= u1 or v0 >= v1:
            continue
        uu = np.arange(u0, u1)[None, :, None, None] + sub[None, None, None, :]
        vv = np.arange(v0, v1)[:, None, None, None] + sub[None, None, :, None]
        cover = (((uu - cu) ** 2 + (vv - cv) ** 2) <= radius_px**2).mean(axis=(2, 3))
        speckle = rng.uniform(0.8, 1.6, cover.shape)
        red = out[v0:v1, u0:u1, 0]
        out[v0:v1, u0:u1, 0] = (1 - cover) * red + cover * np.minimum(255.0, 300.0 * speckle)
        # A little scattered red light raises green/blue slightly.
        out[v0:v1, u0:u1, 1:] += 10.0 * cover[..., None]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def seabed_frame(
    spectrum: np.ndarray,
    offset_uv_px: tuple[float, float],
    seed: int = 0,
    noise_sigma: float = DEFAULT_NOISE_SIGMA,
    vignetting: float = 0.0,
) -> np.ndarray:
    """Convenience: rendered, tinted, noisy ``(272, 360, 3) uint8`` frame without lasers."""
    return colourise(render_grey(spectrum, offset_uv_px), seed=seed, noise_sigma=noise_sigma, vignetting=vignetting)


# ---------------------------------------------------------------------------------------------
# Synthetic measurement streams for the SLAM back ends (no images): a true track over a field
# of point landmarks, turned into the per-frame records both back ends consume.


@dataclass(frozen=True)
class SurveyNoise:
    """Noise of a synthetic measurement stream (what the back ends are told, and the truth's)."""

    speed_sigma_mps: float = 2e-3
    compass_sigma_rad: float = 0.0087  # white
    drift_sigma_rad: float = 0.0087  # slow compass error, Ornstein-Uhlenbeck
    drift_tau_s: float = 120.0
    step_sigma_rad: float = 0.002  # turn measured by the tokens
    pixel_sigma_px: float = 0.5
    altitude_m: float = 1.31
    focal_px: float = 1075.0
    image_wh_px: tuple[int, int] = (360, 272)
    template_px: int = 32  # observed only when the whole template is inside the image


@dataclass(frozen=True)
class Survey:
    """A true track, its landmarks and the measurement records of every frame."""

    xy_m: np.ndarray  # (K, 2) true positions, frame 0 at the origin
    heading_rad: np.ndarray  # (K,) true headings
    landmarks_xy_m: np.ndarray  # (M, 2) true position of landmark id i (in order of creation)
    frames: list  # K FrameMeasurements
    order: list | None = None  # index in the field of landmark id i


def lawnmower_track(n_legs=5, leg_steps=70, cross_steps=15, psi0=0.4, speed_mps=0.1, dt_s=0.2):
    """(K, 2) positions and (K,) headings of a turning grid survey (tests/test_ekf.py's): legs of
    1.4 m, lanes 0.3 m apart, the heading turning with each leg; moves by (1) with R(psi_{k-1})."""
    heads = [psi0]
    for leg in range(n_legs):
        heads += [psi0 + (np.pi if leg % 2 else 0.0)] * leg_steps
        if leg < n_legs - 1:
            heads += [psi0 + np.pi / 2] * cross_steps
    return _integrate(np.array(heads), np.tile([speed_mps, 0.0], (len(heads) - 1, 1)), dt_s)


def crosshatch_track(n_frames, side_m=0.7, lane_m=0.175, speed_mps=0.1, heading_rad=0.0, dt_s=0.2):
    """(K, 2) positions and (K,) headings of the paper's constant-heading survey: a square grid
    flown north-south then east-west (lanes ``lane_m`` apart), over and over, crabbing."""
    corners = []
    n_lanes = int(round(side_m / lane_m)) + 1
    for i in range(n_lanes):  # north-south lanes, stepping east
        y = i * lane_m
        corners += [(0.0, y), (side_m, y)] if i % 2 == 0 else [(side_m, y), (0.0, y)]
    for i in range(n_lanes):  # east-west lanes, stepping north back to the start
        x = side_m - i * lane_m
        corners += [(x, side_m), (x, 0.0)] if i % 2 == 0 else [(x, 0.0), (x, side_m)]
    corners = np.array(corners)
    xy = [np.zeros(2)]
    target = 0
    step = speed_mps * dt_s
    while len(xy) < n_frames:
        d = corners[target] - xy[-1]
        dist = float(np.hypot(*d))
        if dist < 1e-9:
            target = (target + 1) % len(corners)
            continue
        xy.append(xy[-1] + d * min(1.0, step / dist))
    xy = np.array(xy)
    heads = np.full(n_frames, heading_rad)
    v_body = (np.diff(xy, axis=0) / dt_s) @ rot2(heading_rad)  # R^T v
    return _integrate(heads, v_body, dt_s)


def _integrate(heading_rad, v_body_mps, dt_s):
    xy = np.zeros((len(heading_rad), 2))
    for k in range(1, len(heading_rad)):
        xy[k] = xy[k - 1] + rot2(heading_rad[k - 1]) @ v_body_mps[k - 1] * dt_s
    return xy, np.asarray(heading_rad, dtype=np.float64)


def survey_measurements(
    seed,
    xy_m,
    heading_rad,
    landmarks_xy_m,
    noise=SurveyNoise(),
    dt_s=0.2,
    spacing_m=0.15,
    max_observations=8,
    heights_m=None,
):
    """Noisy per-frame records of a true track over a landmark field (seeded).

    Policy, independent of any back end: every mapped landmark whose template is inside the
    image is observed (at most ``max_observations``, nearest the centre first); when none is,
    and no mapped landmark lies within ``spacing_m`` of the vehicle, the unmapped one nearest
    the image centre is initialised. Speed, compass (white + Ornstein-Uhlenbeck drift), token
    turn and pixels get the noise of ``noise``; ``heading_rad`` of a record is the pipeline's
    heading input (heading.HeadingFilter of the compass and the turns). ``heights_m`` (M,): each
    landmark's height above the seabed the altitude refers to (its image depth is the altitude
    minus it; default 0, a flat seabed).
    """
    from rovslam.sensor.heading import HeadingFilter
    from rovslam.slam.measurements import FrameMeasurements, LandmarkMeasurement
    from rovslam.slam.observation import observation_noise_px2, observe_mn

    rng = np.random.default_rng(seed)
    k_frames = len(xy_m)
    z, f = noise.altitude_m, noise.focal_px
    a = np.exp(-dt_s / noise.drift_tau_s)
    bias = np.empty(k_frames)
    bias[0] = rng.normal(0.0, noise.drift_sigma_rad)
    for k in range(1, k_frames):
        bias[k] = a * bias[k - 1] + rng.normal(0.0, noise.drift_sigma_rad * np.sqrt(1.0 - a * a))
    compass = heading_rad + bias + rng.normal(0.0, noise.compass_sigma_rad, k_frames)
    steps = np.diff(heading_rad) + rng.normal(0.0, noise.step_sigma_rad, k_frames - 1)
    q = np.eye(2) * noise.speed_sigma_mps**2
    lim = np.array([noise.image_wh_px[1] / 2 - noise.template_px / 2, noise.image_wh_px[0] / 2 - noise.template_px / 2])
    heading_filter = HeadingFilter(noise.compass_sigma_rad)
    id_of: dict[int, int] = {}  # index in landmarks_xy_m -> landmark id
    order: list[int] = []
    frames = []
    for k in range(k_frames):
        if k == 0:
            speed, dt, step, step_sigma = np.zeros(2), 0.0, np.nan, np.nan
            psi = heading_filter.update(compass[0])
        else:
            true_v = rot2(heading_rad[k - 1]).T @ (xy_m[k] - xy_m[k - 1]) / dt_s
            speed, dt = true_v + rng.normal(0.0, noise.speed_sigma_mps, 2), dt_s
            step, step_sigma = float(steps[k - 1]), noise.step_sigma_rad
            psi = heading_filter.update(compass[k], step, step_sigma)
        mn_all = observe_mn(landmarks_xy_m, xy_m[k], heading_rad[k], z, f)
        if heights_m is not None:  # (3) at the landmark's own depth
            mn_all = mn_all * (z / (z - np.asarray(heights_m)))[:, None]
        inside = np.flatnonzero(np.all(np.abs(mn_all) < lim, axis=1))
        inside = inside[np.argsort(np.sum(mn_all[inside] ** 2, axis=1))]
        obs = []
        tracked = [t for t in inside if t in id_of][:max_observations]
        for t in tracked:
            mn = mn_all[t] + rng.normal(0.0, noise.pixel_sigma_px, 2)
            obs.append(LandmarkMeasurement(id_of[t], "track", mn, observation_noise_px2(mn, noise.pixel_sigma_px, z)))
        if not tracked:
            mapped = landmarks_xy_m[order] if order else np.zeros((0, 2))
            far = not len(mapped) or np.min(np.hypot(*(mapped - xy_m[k]).T)) >= spacing_m
            fresh = [t for t in inside if t not in id_of]
            if far and fresh:
                t = fresh[0]
                id_of[t] = len(order)
                order.append(t)
                mn = mn_all[t] + rng.normal(0.0, noise.pixel_sigma_px, 2)
                obs.append(
                    LandmarkMeasurement(id_of[t], "init", mn, observation_noise_px2(mn, noise.pixel_sigma_px, z))
                )
        frames.append(
            FrameMeasurements(
                index=k,
                t_s=k * dt_s,
                dt_s=dt,
                speed_mps=speed,
                speed_cov_mps2=q,
                speed_ok=k > 0,
                heading_rad=psi,
                heading_sigma_rad=heading_filter.sigma_rad,
                compass_rad=float(compass[k]),
                compass_sigma_rad=noise.compass_sigma_rad,
                heading_step_rad=step,
                heading_step_sigma_rad=step_sigma,
                altitude_m=z,
                altitude_sigma_m=0.0,
                focal_px=f,
                landmarks=tuple(obs),
            )
        )
    return Survey(np.asarray(xy_m), np.asarray(heading_rad), landmarks_xy_m[order].reshape(-1, 2), frames, order)


def landmark_field(seed, xy_m, density_per_m2=30.0, margin_m=0.4):
    """(M, 2) landmarks at random (seeded) over the bounding box of a track plus ``margin_m``."""
    rng = np.random.default_rng(seed)
    lo, hi = xy_m.min(0) - margin_m, xy_m.max(0) + margin_m
    return rng.uniform(lo, hi, (int(density_per_m2 * np.prod(hi - lo)), 2))


def simulate_variant(out_dir, base: str, name: str, seed: int, **fields):
    """Simulate a preset with some of its fields replaced (``n_frames=80, sensor=...``) into ``out_dir``.

    The variant is registered under ``name`` only while it is simulated. Returns ``out_dir``.
    """
    import dataclasses

    from rovslam.sim import SCENARIOS, simulate

    sc = dataclasses.replace(SCENARIOS[base], name=name, **fields)
    SCENARIOS[name] = sc
    try:
        simulate(name, out_dir, seed=seed)
    finally:
        del SCENARIOS[name]
    return out_dir


def photo_available() -> bool:
    """Whether the shared real seabed photo (chamber3) is there for the photo presets."""
    from rovslam import data

    return data.available("chamber3")
