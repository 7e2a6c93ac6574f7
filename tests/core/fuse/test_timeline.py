"""Event stream, coverage, output stamps and the one-line refusals of ``prepare``."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.fuse.inputs import FuseInputs, FuseOptions, GpsSeries, ImuSeries, PoseSeries, WheelSeries
from lio_cli.core.fuse.timeline import IMU, ODOM, OUT, prepare
from lio_cli.errors import ConfigError, InputError

MS = 1_000_000
T0 = 1_700_000_000 * 10**9


def imu_series(stamps: np.ndarray) -> ImuSeries:
    n = len(stamps)
    return ImuSeries(stamps, np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)), np.eye(4))


def test_rate_output_meets_ground_truth_stamps_and_skips_gaps():
    # IMU at 200 Hz for 1 s, a 10 s gap, then 1 s more
    st = np.concatenate([T0 + np.arange(201) * 5 * MS, T0 + 11_000 * MS + np.arange(201) * 5 * MS])
    prep = prepare(FuseInputs(imu=imu_series(st)), FuseOptions(estimator="ekf", rate_hz=100.0))
    assert prep.coverage == [(T0, T0 + 1000 * MS), (T0 + 11_000 * MS, T0 + 12_000 * MS)]
    assert len(prep.out_stamps) == 202  # 101 per covered second, none in the gap
    assert np.all(prep.out_stamps % (10 * MS) == 0)
    assert prep.reports["imu"].notes["gaps"] == 1


def test_events_sorted_imu_before_measurement_before_output_at_one_stamp():
    st = T0 + np.arange(11) * 10 * MS
    odom = PoseSeries(st[::5].copy(), np.tile(np.eye(4), (3, 1, 1)))
    prep = prepare(FuseInputs(imu=imu_series(st), odom=odom), FuseOptions(estimator="ekf"))
    at = prep.times == st[5]
    np.testing.assert_array_equal(prep.kinds[at], [IMU, ODOM, OUT])
    assert np.all(np.diff(prep.times) >= 0)


def test_explicit_stamps_outside_the_data_are_dropped_and_counted():
    st = T0 + np.arange(11) * 10 * MS
    ask = np.array([T0 - 5 * MS, T0 + 33 * MS, T0 + 200 * MS])
    prep = prepare(FuseInputs(imu=imu_series(st)), FuseOptions(estimator="ekf", stamps_ns=ask))
    np.testing.assert_array_equal(prep.out_stamps, [T0 + 33 * MS])
    assert prep.out_dropped == 2


def test_no_motion_source_is_refused():
    gps = GpsSeries(T0 + np.arange(3), np.zeros((3, 3)))
    with pytest.raises(InputError, match=r"^no motion source: fuse needs an odometry trajectory, an IMU \(gyro\) or wheel odometry$"):
        prepare(FuseInputs(gps=gps), FuseOptions(estimator="ekf"))


def test_sources_on_different_clocks_are_refused():
    st = T0 + np.arange(11) * 10 * MS
    wheel = WheelSeries(np.arange(5, dtype=np.int64) * 20 * MS + 47 * 10**9, np.ones((5, 3)), np.zeros(5))
    with pytest.raises(InputError) as err:
        prepare(FuseInputs(imu=imu_series(st), wheel=wheel), FuseOptions(estimator="ekf", use={"imu": {"gyro"}, "wheel": {"speed"}}))
    assert str(err.value) == ("imu stamps 1700000000.000..1700000000.100 s do not overlap the other sources' "
                              "47.000..47.080 s: the sources are on different clocks")


@pytest.mark.parametrize("rate", [0.0, -5.0, float("nan")])
def test_rate_not_positive_is_a_config_error(rate):
    st = T0 + np.arange(11) * 10 * MS
    with pytest.raises(ConfigError, match=r"^--rate must be a positive number of Hz, got"):
        prepare(FuseInputs(imu=imu_series(st)), FuseOptions(estimator="ekf", rate_hz=rate))


def test_unknown_measurement_and_bad_combinations_are_config_errors():
    st = T0 + np.arange(11) * 10 * MS
    inputs = FuseInputs(imu=imu_series(st))
    cases = [
        (FuseOptions(estimator="ekf", use={"imu": {"gyro", "magnet"}}), "unknown imu measurement 'magnet' in use (choose from gyro, accel, orientation)"),
        (FuseOptions(estimator="ekf", use={"imu": {"accel"}}), "the IMU accelerometer needs the gyro too (use imu gyro,accel)"),
        (FuseOptions(estimator="ekf", use={"odom": {"pose", "delta"}}), "use odom pose or odom delta, not both"),
        (FuseOptions(estimator="ukf"), "unknown estimator 'ukf' (choose from auto, ekf, planar, complementary)"),
    ]
    for options, message in cases:
        with pytest.raises(ConfigError) as err:
            prepare(inputs, options)
        assert str(err.value) == message


def test_an_all_zero_imu_is_ignored_beside_another_motion_source_and_refused_alone():
    st = T0 + np.arange(11) * 10 * MS
    zero = ImuSeries(st, np.zeros((11, 3)), np.zeros((11, 3)), np.eye(4))
    wheel = WheelSeries(st.copy(), np.tile([1.0, np.nan, np.nan], (11, 1)), np.full(11, 0.1))
    prep = prepare(FuseInputs(imu=zero, wheel=wheel), FuseOptions(estimator="ekf"))
    assert prep.use == {"wheel": {"speed", "yaw_rate"}}
    assert prep.notes == ["IMU ignored: no usable sample (all NaN, out of range, all zero or duplicated)"]
    assert prep.reports["imu"].rejected == {"all_zero": 11}
    with pytest.raises(InputError) as err:
        prepare(FuseInputs(imu=zero), FuseOptions(estimator="ekf"))
    assert str(err.value) == ("the IMU has no usable sample (all NaN, out of range, all zero or duplicated) and "
                              "there is no other motion source")


def test_snap_moves_stamps_onto_the_nearest_grid_stamp_within_tolerance():
    from lio_cli.core.fuse.timeline import snap_to

    grid = np.array([0, 10, 20], dtype=np.int64)
    out, n = snap_to(np.array([1, 4, 6, 14, 25, 10], dtype=np.int64), grid, 4)
    np.testing.assert_array_equal(out, [0, 0, 10, 10, 25, 10])
    assert n == 4  # 10 was already on the grid; 25 is too far
    same, n0 = snap_to(np.array([1, 4]), grid, 0)
    np.testing.assert_array_equal(same, [1, 4])
    assert n0 == 0


def test_gap_free_until_is_the_end_of_the_stretch_holding_the_stamp():
    from lio_cli.core.fuse.timeline import gap_free_until, in_coverage_gap

    starts, ends = [0, 100, 300], [50, 200, 400]
    assert [gap_free_until(starts, ends, t) for t in (-5, 0, 49, 50, 70, 100, 199, 200, 350, 400, 500)] == \
        [-5, 50, 50, 50, 70, 200, 200, 200, 400, 400, 500]
    for t in range(-10, 510, 7):  # no step starting in [t, gap_free_until) lies in a gap
        for t_a in range(t, gap_free_until(starts, ends, t)):
            assert not in_coverage_gap(starts, ends, t_a, t_a + 3)


def test_outputs_at_another_events_stamp_fold_into_it():
    from lio_cli.core.fuse.timeline import WHEEL, folded_outputs

    st = T0 + np.arange(11) * 10 * MS
    odom = PoseSeries(st[::5].copy(), np.tile(np.eye(4), (3, 1, 1)))
    prep = prepare(FuseInputs(imu=imu_series(st), odom=odom), FuseOptions(estimator="ekf", stamps_ns=[st[5], st[5] + 3 * MS]))
    times, kinds, index, out = folded_outputs(prep)
    assert len(times) == len(prep.times) - 1  # the output at st[5] folds into the odometry there
    at = [j for j, t in enumerate(times) if t == st[5]]
    assert [kinds[j] for j in at] == [IMU, ODOM] and [out[j] for j in at] == [False, True]
    own = times.index(int(st[5] + 3 * MS))  # between IMU samples: an event of its own
    assert kinds[own] == OUT and out[own] and sum(out) == 2
    assert WHEEL not in kinds
