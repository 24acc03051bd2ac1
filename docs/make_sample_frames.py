"""Write the README's sample frames of the simulator (``docs/img/sample_*.png``).

Run: ``python docs/make_sample_frames.py`` (under a minute). Three frames of the same
procedural seabed (seed 7) with the ``portofino`` camera at 1.31 m, rendered with sensor
noise like every simulated frame:

* ``sample_plain.png`` - clear water, lamps, no lasers;
* ``sample_turbid.png`` - the turbid water with marine snow of the ``rough-turns`` preset;
* ``sample_lasers.png`` - clear water with the four red laser spots of the paper's rig;

and one frame of each of the harder presets (its world for seed 7, a pose of
its survey), exactly as ``rovslam simulate`` renders it:

* ``sample_relief.png`` (``portofino-relief``), ``sample_hd.png`` (``hd-survey``, scaled to
  640x360), ``sample_turbid_relief.png``, ``sample_coral.png``, ``sample_swell.png``. (No
  sample of the photo presets: the chamber3 photo is test data whose licence is unknown,
  and a rendered frame of it would be a copy of part of it.)
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from rovslam.errors import SimulationError
from rovslam.sim import (
    PAPER_LASERS,
    PORTOFINO_CAMERA,
    SCENARIOS,
    Pose,
    World,
    frame_pose,
    frame_rng,
    render_frame,
    renderer_for,
    simulate_trajectory,
)
from rovslam.sim.scenarios import build_world

OUT = Path(__file__).resolve().parent / "img"
SEED = 7


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    world = World.procedural(SEED)
    plain = SCENARIOS["portofino"]
    rough = SCENARIOS["rough-turns"]
    shots = {
        "sample_plain.png": (Pose(0.12, -0.30, 1.31, 0.0), (), plain.water, (0.08, 0.02)),
        "sample_turbid.png": (Pose(-0.20, 0.25, 1.31, 0.6, 0.01, -0.012), (), rough.water, (0.06, 0.0)),
        "sample_lasers.png": (Pose(0.30, 0.10, 1.31, 0.0), PAPER_LASERS, plain.water, (0.0, 0.10)),
    }
    for k, (name, (pose, lasers, water, vel)) in enumerate(shots.items()):
        img = render_frame(
            world,
            PORTOFINO_CAMERA,
            pose,
            lasers,
            water,
            np.random.default_rng([SEED, k]),
            sensor=plain.sensor,
            spots=plain.spots,
            velocity_mps=vel,
            t_s=10.0,
        )
        cv2.imwrite(str(OUT / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        print(f"wrote {OUT / name}")
    for name, preset, k in HARD_SHOTS:
        write_preset_frame(name, preset, k)


# (file, preset, frame index of its survey for seed 7)
HARD_SHOTS = (
    ("sample_relief.png", "portofino-relief", 400),
    ("sample_hd.png", "hd-survey", 500),
    ("sample_turbid_relief.png", "turbid-relief", 300),
    ("sample_coral.png", "coral-repetitive", 900),
    ("sample_swell.png", "swell", 600),
)


def write_preset_frame(name: str, preset: str, k: int) -> None:
    """Frame ``k`` of ``preset`` for seed 7 as ``rovslam simulate`` renders it (without the H.264 round trip)."""
    sc = SCENARIOS[preset]
    traj = simulate_trajectory(sc.vehicle, sc.grid, k + 1, sc.frame_rate_hz, SEED)
    try:
        world, _ = build_world(sc, SEED)
    except SimulationError as exc:
        print(f"skipped {name}: {exc}")
        return
    img = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots, sc.lighting).render(
        world,
        frame_pose(traj, k),
        sc.lasers,
        frame_rng(SEED, k),
        velocity_mps=(float(traj.surge_mps[k]), float(traj.sway_mps[k])),
        t_s=float(traj.t_s[k]),
    )
    if img.shape[1] > 640:
        img = cv2.resize(img, (640, img.shape[0] * 640 // img.shape[1]), interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(OUT / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    print(f"wrote {OUT / name}")


if __name__ == "__main__":
    main()
