"""Write the README's sample frames of the simulator (``docs/img/sample_*.png``).

Run: ``python docs/make_sample_frames.py`` (a few seconds). Three frames of the same
procedural seabed (seed 7) with the ``portofino`` camera at 1.31 m, rendered with sensor
noise like every simulated frame:

* ``sample_plain.png`` - clear water, lamps, no lasers;
* ``sample_turbid.png`` - the turbid water with marine snow of the ``rough-turns`` preset;
* ``sample_lasers.png`` - clear water with the four red laser spots of the paper's rig.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from rovslam.sim import PAPER_LASERS, PORTOFINO_CAMERA, SCENARIOS, Pose, World, render_frame

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
            world, PORTOFINO_CAMERA, pose, lasers, water, np.random.default_rng([SEED, k]),
            sensor=plain.sensor, spots=plain.spots, velocity_mps=vel, t_s=10.0,
        )
        cv2.imwrite(str(OUT / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        print(f"wrote {OUT / name}")


if __name__ == "__main__":
    main()
