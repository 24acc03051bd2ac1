"""Seabed textures: deterministic per seed, seamless across chunks, not tiled, multi-scale; image seabeds."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rovslam.errors import SimulationError
from rovslam.sim import ImageSeabed, ProceduralSeabed, TextureParams, World
from rovslam.sim._noise import lattice_noise_grid, lattice_noise_points

SMALL = TextureParams(chunk_texels=128)  # small chunks: cheap tests, many seams


@pytest.fixture(scope="module")
def seabed():
    return ProceduralSeabed(SMALL, seed=4)


def test_same_seed_same_seabed_other_seed_other_seabed(seabed):
    a = seabed.region(-100, -50, 300, 260)
    b = ProceduralSeabed(SMALL, seed=4).region(-100, -50, 300, 260)
    c = ProceduralSeabed(SMALL, seed=5).region(-100, -50, 300, 260)
    assert a.dtype == np.uint8 and a.shape == (300, 260, 3)
    np.testing.assert_array_equal(a, b)
    assert np.mean(np.abs(a.astype(int) - c.astype(int))) > 10


def test_chunk_size_does_not_change_the_seabed(seabed):
    """Features are functions of world position: 128- and 192-texel chunks give the same texels."""
    a = seabed.region(-200, -200, 400, 400).astype(int)
    b = ProceduralSeabed(TextureParams(chunk_texels=192), seed=4).region(-200, -200, 400, 400).astype(int)
    assert np.mean(np.abs(a - b)) < 0.1
    assert np.max(np.abs(a - b)) <= 1  # float rounding at most


def test_no_seams_at_chunk_borders(seabed):
    img = seabed.region(0, 0, 512, 512).astype(float).mean(axis=2)
    step = np.abs(np.diff(img, axis=1))  # difference between neighbouring columns
    at_seams = step[:, [127, 255, 383]].mean()
    elsewhere = np.delete(step, [127, 255, 383], axis=1).mean()
    assert at_seams < 1.3 * elsewhere


def test_no_tiling():
    """Detail (high-passed texture) one chunk period apart, or at any shift, is uncorrelated."""
    src = ProceduralSeabed(TextureParams(chunk_texels=256), seed=2)
    img = src.region(0, 0, 1024, 1024).astype(np.float32).mean(axis=2)
    detail = img - cv2.GaussianBlur(img, (0, 0), 6.0)
    ref = detail[:512, :512]
    for dr, dc in ((256, 0), (0, 256), (256, 256), (512, 0), (0, 512), (512, 512), (100, 300)):
        other = detail[dr : dr + 512, dc : dc + 512]
        assert abs(np.corrcoef(ref.ravel(), other.ravel())[0, 1]) < 0.05


def test_structure_at_several_scales(seabed):
    """Contrast from millimetre grains to decimetre patches (8-bit albedo units)."""
    img = seabed.region(-600, -600, 1200, 1200).astype(np.float32).mean(axis=2)
    stds = []
    for size_texels in (4, 40, 400):  # 2 mm, 2 cm, 20 cm
        blurred = cv2.blur(img, (size_texels, size_texels))
        band = blurred - cv2.blur(img, (size_texels * 3, size_texels * 3))
        stds.append(float(band.std()))
    assert min(stds) > 2.0, stds
    # Darker and brighter areas: 10-cm block means vary.
    blocks = img[: 1200 // 200 * 200, :].reshape(6, 200, 6, 200).mean(axis=(1, 3))
    assert blocks.std() > 4.0


def test_lattice_noise_grid_and_points_agree():
    grid = lattice_noise_grid(9, 3, 0.01, -0.02, 50, 60, 0.0005, 0.004)
    rows = np.array([0, 7, 49, 20])
    cols = np.array([0, 59, 13, 33])
    pts = lattice_noise_points(9, 3, 0.01 + 0.0005 * rows, -0.02 + 0.0005 * cols, 0.004)
    np.testing.assert_allclose(grid[rows, cols], pts, rtol=1e-4, atol=1e-5)
    big = lattice_noise_grid(1, 1, 0.0, 0.0, 400, 400, 0.001, 0.004)
    assert big.std() == pytest.approx(1.0, abs=0.15)


def test_image_seabed_orientation_scale_and_mirroring():
    img = np.zeros((20, 30, 3), np.uint8)
    img[..., 0] = np.arange(20, dtype=np.uint8)[:, None]  # row index in red
    img[..., 1] = np.arange(30, dtype=np.uint8)[None, :]  # column index in green
    src = ImageSeabed(img, mm_per_px=2.0)
    assert src.texel_m == pytest.approx(0.002)
    # Global texel (0, 0) is the image centre pixel (9, 14); +rows go north = image up.
    reg = src.region(0, 0, 3, 3)
    assert reg[0, 0, 0] == 9 and reg[0, 0, 1] == 14
    assert reg[1, 0, 0] == 8 and reg[0, 1, 1] == 15
    # Beyond the border the image is mirrored (edge pixel repeated).
    far = src.region(9, 15, 3, 3)  # rows 9, 10, 11 -> image rows 0, 0, 1; cols 29, 29, 28
    assert list(far[:, 0, 0]) == [0, 0, 1]
    assert list(far[0, :, 1]) == [29, 29, 28]


def test_texture_files(tmp_path):
    photo = (np.random.default_rng(0).random((64, 80, 3)) * 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "seabed.png"), photo)
    world = World.from_image(tmp_path / "seabed.png", 1.0)
    np.testing.assert_array_equal(world.seabed.region(-32, -39, 64, 80)[::-1], photo[..., ::-1])
    (tmp_path / "notes.txt").write_text("not an image")
    with pytest.raises(SimulationError, match="not an image"):
        World.from_image(tmp_path / "notes.txt", 1.0)
    with pytest.raises(SimulationError, match="does not exist"):
        World.from_image(tmp_path / "missing.png", 1.0)
    with pytest.raises(SimulationError, match="mm per pixel"):
        World.from_image(tmp_path / "seabed.png", 0.0)


def test_bad_texture_params():
    with pytest.raises(SimulationError, match="texel_mm"):
        TextureParams(texel_mm=0.0)
    with pytest.raises(SimulationError, match="weed_cover"):
        TextureParams(weed_cover=1.5)
