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
"""

from __future__ import annotations

import numpy as np

from rovslam.camera import Camera, LaserPointer, ground_to_pixels

DEFAULT_NOISE_SIGMA = 3.0  # 8-bit grey levels, per channel


def paper_camera() -> Camera:
    return Camera(width_px=360, height_px=272, fx_px=1075.0, fy_px=1075.0, cx_px=179.5, cy_px=135.5)


def paper_lasers() -> tuple[LaserPointer, ...]:
    return tuple(
        LaserPointer(origin_m=(sx * 0.05, sy * 0.05, 0.0)) for sx in (1, -1) for sy in (1, -1)
    )


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
        t = (altitude_m + slope_fwd * o[0] + slope_stbd * o[1] - o[2]) / (
            d[2] - slope_fwd * d[0] - slope_stbd * d[1]
        )
        p = o + t * d
        out.append(ground_to_pixels(camera, p[None, :2], p[2])[0])
    return np.array(out)


def draw_laser_spots(
    rgb: np.ndarray, spots_uv_px: np.ndarray, seed: int = 0, radius_px: float = 2.5
) -> np.ndarray:
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
    return colourise(render_grey(spectrum, offset_uv_px), seed=seed, noise_sigma=noise_sigma,
                     vignetting=vignetting)
