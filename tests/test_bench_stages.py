"""The per-stage benchmark names the library's step methods by import path; a rename in the
library must fail here, in ``make test``, not months later in ``python -m benchmarks pipeline``."""

import pytest

from benchmarks._stages import STAGES, MissingTarget, StageClock, resolve


@pytest.mark.parametrize("target", [t for _, targets in STAGES for t in targets])
def test_every_stage_target_still_exists(target):
    owner, attr, value = resolve(target)
    assert callable(value) and getattr(owner, attr) is not None


def test_a_renamed_target_is_named_with_the_file_to_update():
    with pytest.raises(MissingTarget, match=r"rovslam.pipeline has no attribute 'no_such_step'.*_stages.py"):
        resolve("rovslam.pipeline:no_such_step")


def test_exclusive_times_add_up_to_the_total():
    ticks = iter(range(100))
    clock = StageClock(clock=lambda: float(next(ticks)))

    def inner():
        return 1

    timed_inner = clock.wrap("inner", inner)
    out, total = clock.timed_total(lambda: timed_inner() + timed_inner())
    assert out == 2
    # ticks: 0 total starts, 1 glue starts, 2-3 and 4-5 the inner calls, 6 glue ends, 7 total ends
    assert clock.seconds["inner"] == 2.0  # each inner call spans one tick
    assert clock.seconds["loop and glue"] == 3.0  # the glue's 5 ticks less the inner calls' 2: exclusive
    assert total == 7.0


def test_the_library_profile_counts_each_loop_sample_by_its_innermost_frame():
    from benchmarks.profile_libraries import LOOP_FRAME, tally

    loop = f"<module> (run.py:1);{LOOP_FRAME}rovslam/pipeline/loop.py:166);_steps (rovslam/pipeline/loop.py:182)"
    raw = [
        f"{loop};match_template (rovslam/vision/tracking.py:186);0x7f00 (cv2.abi3.so) 6",
        f"{loop};median0 (rovslam/averages.py:36);array_subscript (numpy/_core/_multiarray_umath.cpython-311.so) 3",
        f"{loop};median0 (rovslam/averages.py:36);DOUBLE_subtract_X86_V3 (numpy/_core/_multiarray_umath.so) 1",
        f"{loop};fuse (rovslam/vision/laser.py:9);fromnumeric (numpy/_core/fromnumeric.py:86) 2",
        f"{loop};fuse (rovslam/vision/laser.py:9);0x7f11 (libc.so.6) 4",
        "<module> (run.py:1);read_image (rovslam/io/sequence.py:443);0x7f00 (cv2.abi3.so) 50",  # outside the loop
        "not a sample line",
    ]
    total, kinds, funcs = tally(raw)
    assert total == 16
    assert kinds == {"OpenCV": 6, "NumPy dispatch": 3, "NumPy compute": 1, "Python": 2, "C library": 4}
    assert funcs["median0  averages.py"] == 4 and funcs["fuse  vision/laser.py"] == 6
    assert funcs["match_template  vision/tracking.py"] == 6
