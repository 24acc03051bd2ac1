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
