"""rovslam live, the pure parts: message fields (frames, units, covariance), telemetry interpolation, options."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovslam.errors import InvalidArgumentError
from rovslam.live import messages as m
from rovslam.live.mavlink import MESSAGES_OUT, parse_mavlink_out
from rovslam.live.session import percentiles_ms
from rovslam.live.stream import _StreamClock, resolve_video
from rovslam.live.telemetry import ClockMap, Telemetry, TimeSeries, unwrap_to


def estimate(**kw) -> m.Estimate:
    base = dict(
        t_s=1.0,
        x_m=2.0,
        y_m=-1.0,
        heading_rad=math.pi / 2,
        roll_rad=0.01,
        pitch_rad=-0.02,
        cov_xy_m2=np.array([[0.04, 0.01], [0.01, 0.09]]),
        surge_mps=0.3,
        sway_mps=0.1,
        speed_cov_mps2=np.array([[1e-4, 0.0], [0.0, 4e-4]]),
        speed_ok=True,
        altitude_m=1.234,
        altitude_sigma_m=0.02,
        altitude_source="laser",
        yaw_sigma_rad=0.01,
        attitude_sigma_rad=0.002,
    )
    base.update(kw)
    return m.Estimate(**base)


def test_position_estimate_is_ned_with_the_filters_covariance_in_the_upper_triangle():
    e = estimate()
    f = m.position_estimate(e, 123, 2)
    assert (f["x"], f["y"], f["z"]) == (2.0, -1.0, 0.0)  # x north, y east (the filter's world), z not estimated
    assert f["yaw"] == pytest.approx(math.pi / 2) and f["roll"] == 0.01 and f["pitch"] == -0.02
    cov = f["covariance"]
    assert len(cov) == 21
    # row-major upper triangle of (x, y, z, roll, pitch, yaw): [0]=xx, [1]=xy, [6]=yy, [11]=zz, [15], [18], [20]
    assert cov[0] == 0.04 and cov[1] == 0.01 and cov[6] == 0.09
    assert cov[11] == pytest.approx(0.02**2) and cov[15] == cov[18] == pytest.approx(0.002**2)
    assert cov[20] == pytest.approx(0.01**2)
    assert sum(abs(c) for i, c in enumerate(cov) if i not in (0, 1, 6, 11, 15, 18, 20)) == 0.0
    assert f["reset_counter"] == 2 and m.position_estimate(e, 0, 257)["reset_counter"] == 1  # uint8


def test_speed_estimate_turns_the_body_speed_into_ned_with_its_covariance():
    e = estimate(heading_rad=math.pi / 2)  # facing east: surge is east, sway (starboard) is south
    f = m.speed_estimate(e, 0, 0)
    assert f["x"] == pytest.approx(-0.1) and f["y"] == pytest.approx(0.3) and f["z"] == 0.0
    c = np.array(f["covariance"]).reshape(3, 3)
    assert c[0, 0] == pytest.approx(4e-4) and c[1, 1] == pytest.approx(1e-4) and c[2, 2] == pytest.approx(4e-4)
    assert c[0, 1] == pytest.approx(0.0, abs=1e-12)


def test_position_delta_is_in_the_current_body_frame():
    prev = estimate(t_s=1.0, x_m=0.0, y_m=0.0, heading_rad=0.0)
    cur = estimate(t_s=1.25, x_m=0.0, y_m=0.5, heading_rad=math.pi / 2)  # moved 0.5 m east, now facing east
    f = m.position_delta(prev, cur, 99)
    assert f["time_delta_usec"] == 250000
    assert f["position_delta"] == pytest.approx([0.5, 0.0, 0.0], abs=1e-12)  # straight ahead in the new body frame
    assert f["angle_delta"] == pytest.approx([0.0, 0.0, math.pi / 2])
    assert 0 < f["confidence"] <= 100


def test_confidence_falls_with_the_speed_sigma_and_is_zero_without_a_speed():
    sharp = m.confidence_percent(estimate(speed_cov_mps2=np.eye(2) * 1e-6))
    half = m.confidence_percent(estimate(speed_cov_mps2=np.eye(2) * m.CONFIDENCE_SIGMA_MPS**2))
    assert sharp > 99.9 and half == pytest.approx(50.0)
    assert m.confidence_percent(estimate(speed_ok=False)) == 0.0


def test_distance_sensor_is_downward_in_cm_with_its_variance_in_cm2():
    f = m.distance_sensor(estimate(altitude_m=1.234, altitude_sigma_m=0.02), 5000, 0.05, 30.0)
    assert f["orientation"] == 25 and f["current_distance"] == 123 and f["covariance"] == 4
    assert (f["min_distance"], f["max_distance"]) == (5, 3000)
    assert m.distance_sensor(estimate(altitude_sigma_m=1.0), 0, 0.05, 30.0)["covariance"] == 254  # capped
    assert m.distance_sensor(estimate(altitude_sigma_m=float("nan")), 0, 0.05, 30.0)["covariance"] == 255  # unknown


def test_time_series_interpolates_holds_briefly_and_refuses_gaps():
    ts = TimeSeries(hold_s=0.3)
    for t in (0.0, 0.1, 0.2):
        ts.add(t, (10 * t,))
    assert ts.at(0.15)[0] == pytest.approx(1.5)
    assert ts.at(0.105)[0] == pytest.approx(1.0)  # within 10 ms of a sample: that sample, as it is
    assert ts.at(0.4)[0] == pytest.approx(2.0) and ts.at(0.6) is None  # held 0.3 s, then nothing
    ts.add(5.0, (50.0,))
    assert ts.at(3.0) is None  # inside a gap of 4.8 s: no interpolation across it


def test_yaw_is_unwrapped_before_interpolating():
    tel = Telemetry()
    tel.add_attitude(0.0, 0.0, 0.0, math.pi - 0.05, 0.0)
    tel.add_attitude(0.1, 0.0, 0.0, -math.pi + 0.05, 0.1)  # crossed +-pi going on turning right
    yaw = tel.attitude_at(0.05)[2]  # halfway: interpolated
    assert yaw == pytest.approx(math.pi)
    assert unwrap_to(-3.0, 3.0) == pytest.approx(2 * math.pi - 3.0)


def test_telemetry_gap_is_recorded_and_the_clock_map_takes_the_smallest_delay():
    tel = Telemetry()
    tel.add_attitude(0.0, 0, 0, 0, arrival_s=0.0)
    tel.add_attitude(2.5, 0, 0, 0, arrival_s=2.5)
    assert tel.summary(2.6)["telemetry_gaps"][0]["gap_s"] == pytest.approx(2.5)
    cm = ClockMap()
    assert cm.local_s(10.0, 100.3) == pytest.approx(100.3)
    assert cm.local_s(10.1, 100.2) == pytest.approx(100.2)  # a faster packet: the offset is now 90.1
    assert cm.local_s(10.2, 100.9) == pytest.approx(100.3)  # a late packet does not move its sample


def test_stream_clock_counts_from_the_first_frame_and_survives_a_restarted_sender():
    c = _StreamClock()
    assert c.t_s(1000.0, 5.0) == 0.0 and c.t_s(1000.1, 5.1) == pytest.approx(0.1)
    assert c.t_s(3.0, 8.1) == pytest.approx(3.1)  # the sender restarted 3 s later: its times went back
    assert c.t_s(3.1, 8.2) == pytest.approx(3.2)


def test_mavlink_out_names():
    assert parse_mavlink_out(None) == MESSAGES_OUT and parse_mavlink_out("all") == MESSAGES_OUT
    assert parse_mavlink_out("position, distance") == ("VISION_POSITION_ESTIMATE", "DISTANCE_SENSOR")
    assert parse_mavlink_out("none") == ()
    with pytest.raises(InvalidArgumentError, match="not a message rovslam sends"):
        parse_mavlink_out("position,odometry")


def test_video_inputs(tmp_path):
    sdp = resolve_video("rtp://0.0.0.0:5600", tmp_path)
    assert sdp.format == "sdp" and sdp.options["protocol_whitelist"] == "file,udp,rtp"
    assert "m=video 5600 RTP/AVP 96" in (tmp_path / "stream.sdp").read_text()
    assert "a=rtpmap:96 H264/90000" in (tmp_path / "stream.sdp").read_text()
    assert resolve_video("/dev/video0").format == "v4l2"
    assert not resolve_video("udp://127.0.0.1:5600").is_file
    from rovslam.errors import SequenceFormatError

    with pytest.raises(SequenceFormatError, match="not found"):
        resolve_video(str(tmp_path / "nothing.ts"))


def test_latency_percentiles():
    p = percentiles_ms([0.01 * k for k in range(1, 101)])
    assert p["p50"] == pytest.approx(505.0) and p["max"] == pytest.approx(1000.0) and p["count"] == 100
    assert percentiles_ms([])["p99"] is None


def test_a_frame_just_past_the_newest_attitude_gets_it_moved_on_by_its_rates_without_waiting():
    tel = Telemetry()
    tel.add_attitude(0.0, 0.0, 0.0, 1.0, arrival_s=0.0, rates_rad_s=(0.1, -0.2, 0.5))
    tel.add_attitude(0.04, 0.004, -0.008, 1.02, arrival_s=0.04, rates_rad_s=(0.1, -0.2, 0.5))
    roll, pitch, yaw = tel.attitude_at(0.07)  # 30 ms past the newest sample
    assert (roll, pitch, yaw) == pytest.approx((0.007, -0.014, 1.035))
    roll, pitch, yaw = tel.attitude_at(0.3)  # 0.26 s past: moved on by 0.1 s at most, then held
    assert yaw == pytest.approx(1.07) and tel.attitude_at(0.4) is None  # beyond the hold: nothing
    assert tel.attitude_at(0.02)[2] == pytest.approx(1.01)  # between two samples: interpolated, as before
    # waiting: never for a frame within 0.1 s of the newest sample (the clock is not read twice)...
    clock = iter([0.07, 0.07])
    assert tel.wait_attitude(0.07, late_s=0.5, now=lambda: next(clock))[2] == pytest.approx(1.035)
    # ... while a frame 0.2 s past it waits (here until late_s, no sample coming), then holds what it can
    t = [0.24]
    waited = tel.wait_attitude(0.24, late_s=0.05, now=lambda: t.__setitem__(0, t[0] + 0.03) or t[0])
    assert waited[2] == pytest.approx(1.07) and t[0] >= 0.24 + 0.05


def test_an_attitude_without_rates_is_held_past_the_newest_sample():
    tel = Telemetry()
    tel.add_attitude(0.0, 0.0, 0.0, 1.0, arrival_s=0.0)
    tel.add_attitude(0.04, 0.0, 0.0, 1.02, arrival_s=0.04, rates_rad_s=(math.nan, 0.0, 0.0))
    assert tel.attitude_at(0.09) == pytest.approx((0.0, 0.0, 1.02))
