"""Textures that fool correlation: repetitive coral, look-alike blobs, low-contrast mud, faint laser spots."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rovslam.errors import SimulationError
from rovslam.sim import PAPER_LASERS, PORTOFINO_CAMERA, SCENARIOS, Pose, SensorParams, World, render_frame
from rovslam.sim.texture import ProceduralSeabed, TextureParams

CAM = PORTOFINO_CAMERA
BARE = dict(
    weed_cover=0.0,
    pebble_density_per_m2=0.0,
    shell_density_per_m2=0.0,
    stone_density_per_m2=0.0,
    burrow_density_per_m2=0.0,
)


def _second_peaks(img: np.ndarray, half: int = 8, search: int = 24, exclude: int = 4) -> np.ndarray:
    """For 16x16 tokens on a grid: the best correlation elsewhere than at the token's own place (+-exclude px)."""
    g = img[..., 1]
    out = []
    for u in range(40, CAM.width_px - 40, 25):
        for v in range(40, CAM.height_px - 40, 25):
            tpl = g[v - half : v + half, u - half : u + half]
            win = g[v - half - search : v + half + search, u - half - search : u + half + search]
            r = cv2.matchTemplate(win, tpl, cv2.TM_CCOEFF_NORMED)
            r[search - exclude : search + exclude + 1, search - exclude : search + exclude + 1] = -1.0
            out.append(r.max())
    return np.array(out)


def test_coral_lattice_gives_tokens_a_wrong_match_as_good_as_the_paper_threshold():
    coral = World.procedural(3, TextureParams(coral_cover=0.89, **BARE))
    sand = World.procedural(3, TextureParams(**BARE))
    peaks = {}
    for name, world in (("coral", coral), ("sand", sand)):
        peaks[name] = np.concatenate(
            [
                _second_peaks(render_frame(world, CAM, Pose(x, 0.2, 1.31), sensor=SensorParams(), noise_free=True))
                for x in (0.0, 0.5)
            ]
        )
    # On coral most tokens find a second place, one corallite away, above the paper's 0.89.
    assert np.median(peaks["coral"]) > 0.92
    assert np.median(peaks["sand"]) < 0.7


def test_mud_hides_the_texture_beneath_it():
    base = TextureParams()
    muddy = TextureParams(mud_cover=0.4, mud_contrast=0.15)
    a = ProceduralSeabed(base, 9).region(-1024, -1024, 2048, 2048)[..., 1].astype(np.float32)
    b = ProceduralSeabed(muddy, 9).region(-1024, -1024, 2048, 2048)[..., 1].astype(np.float32)

    def local_contrast(g: np.ndarray) -> np.ndarray:
        mean = cv2.blur(g, (9, 9))
        return np.sqrt(np.maximum(cv2.blur(g * g, (9, 9)) - mean * mean, 0.0))[::9, ::9]

    ca, cb = local_contrast(a), local_contrast(b)
    smooth = cb < 0.3 * np.median(ca)
    assert (ca < 0.3 * np.median(ca)).mean() < 0.05
    assert 0.2 < smooth.mean() < 0.6  # about 40 % of the seabed under low-contrast mud
    untouched = (a == b)[::9, ::9]
    assert 0.1 < untouched.mean() < 0.8  # elsewhere (beyond the mud's soft edges) the seabed is as it was


def test_urchins_are_dark_look_alike_blobs():
    seabed = ProceduralSeabed(TextureParams(urchin_density_per_m2=60.0, **BARE), 4)
    plain = ProceduralSeabed(TextureParams(**BARE), 4)
    a = seabed.region(0, 0, 2048, 2048)[..., 1].astype(np.float32)
    b = plain.region(0, 0, 2048, 2048)[..., 1].astype(np.float32)
    dark = (a < 0.5 * b).astype(np.uint8)
    n, _, stats, centres = cv2.connectedComponentsWithStats(dark)
    areas = stats[1:, cv2.CC_STAT_AREA] * 0.25  # mm^2
    assert 30 <= np.sum(areas > 100.0) <= 110  # about 60 per square metre
    # Seen by the camera (about 1.2 mm per pixel): isolated urchins correlate with one another.
    seen = cv2.GaussianBlur(a, (0, 0), 1.2)
    patches = []
    for (cx, cy), area in zip(centres[1:], areas):
        x, y = int(round(cx)), int(round(cy))
        if 200.0 < area < 1600.0 and 40 <= x < 2008 and 40 <= y < 2008:
            patches.append(seen[y - 40 : y + 40, x - 40 : x + 40].ravel())
    assert len(patches) >= 15
    ncc = np.corrcoef(np.array(patches))[np.triu_indices(len(patches), 1)]
    rng = np.random.default_rng(0)
    sand = [
        cv2.GaussianBlur(b, (0, 0), 1.2)[y - 40 : y + 40, x - 40 : x + 40].ravel()
        for x, y in rng.integers(40, 2008, (len(patches), 2))
    ]
    sand_ncc = np.corrcoef(np.array(sand))[np.triu_indices(len(sand), 1)]
    assert np.median(ncc) > 0.6  # any urchin looks much like any other
    assert np.median(np.abs(sand_ncc)) < 0.35  # two places on the (rippled) sand much less


def test_faint_laser_spots_bleed_into_the_green_channel():
    sc = SCENARIOS["coral-repetitive"]
    world = World.procedural(2, TextureParams(**BARE))
    pose = Pose(0.0, 0.0, 1.31)
    with_spots = render_frame(
        world, CAM, pose, PAPER_LASERS, sc.water, sensor=sc.sensor, spots=sc.spots, noise_free=True
    ).astype(int)
    without = render_frame(world, CAM, pose, (), sc.water, sensor=sc.sensor, noise_free=True).astype(int)
    bright = SCENARIOS["portofino"]
    strong = render_frame(
        world, CAM, pose, PAPER_LASERS, bright.water, sensor=bright.sensor, spots=bright.spots, noise_free=True
    ).astype(int)
    for u, v in ((CAM.cx_px + 41.0, CAM.cy_px - 41.0), (CAM.cx_px - 41.0, CAM.cy_px + 41.0)):
        win = (slice(int(v) - 3, int(v) + 5), slice(int(u) - 3, int(u) + 5))
        red = with_spots[win][..., 0].max()
        green_gain = (with_spots[win][..., 1] - without[win][..., 1]).max()
        assert red < 200  # faint: not saturated, unlike the original rig
        assert strong[win][..., 0].max() == 255
        assert green_gain >= 15  # and it spills into the green channel the tokens are tracked in


def test_new_texture_parameters_are_validated():
    with pytest.raises(SimulationError, match="coral_cover"):
        TextureParams(coral_cover=0.95)
    with pytest.raises(SimulationError, match="urchin_radius_mm"):
        TextureParams(urchin_radius_mm=0.0)
    with pytest.raises(SimulationError, match="mud_contrast"):
        TextureParams(mud_contrast=1.5)
