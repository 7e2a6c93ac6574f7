"""The fuse job end to end on hand-checkable logs (a unicycle measured exactly: tests/jobs/conftest.py):
positions against the closed form, what each message carries, messy streams counted, bad input refused with
its exact line, the resolved config repeating the run, chunked runs matching whole ones."""

from __future__ import annotations

import gc

import numpy as np
import pytest

from lio_cli.config import with_overrides
from lio_cli.config.fuse import FuseConfig
from lio_cli.errors import InputError
from lio_cli.jobs.fuse.job import FuseJob, run_fuse

POS_TOL_M = 0.01  # a noise-free unicycle: discretisation only (a broken filter is metres off)
EKF = FuseConfig(estimator="ekf", smooth=False)  # a flat unicycle would get the planar filter; these check the 3D one


def _errors(fuse_logs, run, v: float, w: float) -> np.ndarray:
    tr = run.trajectory
    p, _ = fuse_logs.unicycle((tr.stamps_ns - fuse_logs.T0_NS) * 1e-9, v, w)
    return np.linalg.norm(tr.positions - p, axis=1)


def test_straight_line_ends_where_speed_times_time_says(fuse_logs):
    run = run_fuse(FuseJob(fuse_logs.write(v=1.0, w=0.0, duration_s=5.0)))
    np.testing.assert_allclose(run.trajectory.positions[-1], [5.0, 0.0, 0.0], atol=1e-3)
    assert run.trajectory.stamps_ns[-1] - run.trajectory.stamps_ns[0] == 5 * 10**9
    assert len(run.trajectory) == 501  # every IMU sample at 100 Hz
    assert "moving start at constant velocity" in run.metrics["start"]
    assert gc.isenabled()  # the run pauses the cyclic collector and switches it back on


def test_circle_follows_the_unicycle_and_closes(fuse_logs):
    """v = 1 m/s, w = 0.5 rad/s for one full turn: radius 2 m, back at the start after 4 pi s."""
    run = run_fuse(FuseJob(fuse_logs.write(v=1.0, w=0.5, duration_s=4 * np.pi), EKF))
    assert _errors(fuse_logs, run, 1.0, 0.5).max() < POS_TOL_M
    k = np.argmin(np.abs(run.trajectory.stamps_ns - (fuse_logs.T0_NS + int(2 * np.pi * 1e9))))  # half a turn
    np.testing.assert_allclose(run.trajectory.positions[k], [0.0, 4.0, 0.0], atol=POS_TOL_M)
    m = run.metrics
    # exact wheels: their yaw rate agrees with the gyro and enters beside it (speed and yaw rate per message), but
    # for the first and last message, whose periods reach outside the IMU's span (never weighed)
    assert m["rejected"]["wheel"] == {"yaw_unchecked": 2}
    assert m["sources_used"] == ["imu", "wheel"] and m["updates"]["wheel"] == 2 * len(run.sources.inputs.wheel) - 2
    assert m["core"]["wheel_yaw_check"]["used"]
    assert m["sources"]["imu"]["predictions"] == len(run.sources.inputs.imu)
    assert run.config.use == {"imu": ["accel", "gyro"], "wheel": ["speed"]} and run.config.weigh_wheel_yaw


def test_imu_orientation_enters_only_where_the_message_carries_one(fuse_logs):
    with_or = run_fuse(FuseJob(fuse_logs.write(w=0.5, duration_s=3.0, imu_orientation=True), EKF))
    assert with_or.config.use["imu"] == ["accel", "gyro", "orientation"]
    assert with_or.metrics["sources"]["imu"]["updates_by_kind"]["orientation"]["updates"] == 301
    assert with_or.metrics["core"]["world_yaw_from"] == "imu_orientation"
    assert _errors(fuse_logs, with_or, 1.0, 0.5).max() < POS_TOL_M
    without = run_fuse(FuseJob(fuse_logs.write(w=0.5, duration_s=3.0), EKF))  # orientation_covariance[0] = -1
    assert without.config.use["imu"] == ["accel", "gyro"] and without.metrics["updates"]["imu"] == 0


def test_a_twist_in_the_parent_frame_is_recognised_from_the_poses(fuse_logs):
    log = fuse_logs.write(w=0.5, duration_s=4.0, twist_frame="parent")
    run = run_fuse(FuseJob(log))
    assert run.sources.wheel_twist_frame == "parent" and run.config.input.wheel_twist_frame == "parent"
    assert run.notes and "twist in the parent frame" in run.notes[0]
    assert _errors(fuse_logs, run, 1.0, 0.5).max() < POS_TOL_M
    forced = run_fuse(FuseJob(log, FuseConfig(input={"wheel_twist_frame": "child"})))  # as REP 105 says
    assert _errors(fuse_logs, forced, 1.0, 0.5).max() > 30 * POS_TOL_M


@pytest.mark.parametrize("kind", ["twist_only", "twist_stamped"])
def test_twist_only_wheel_messages_are_enough(fuse_logs, kind):
    log = fuse_logs.write(w=0.5, duration_s=3.0, twist_only=kind == "twist_only",
                          wheel="twist" if kind == "twist_stamped" else "odometry")
    run = run_fuse(FuseJob(log))
    assert _errors(fuse_logs, run, 1.0, 0.5).max() < POS_TOL_M
    assert run.metrics["updates"]["wheel"] == 61


def test_messy_streams_are_handled_and_counted(fuse_logs):
    """One IMU sample duplicated, one NaN, two recorded late (out of order), half a second missing; wheel
    covariances -1 (unknown), one NaN speed, one duplicate: the run goes on and says what it met."""
    def edit(topic, msgs):
        if topic == "/imu":
            msgs = list(msgs)
            msgs.insert(50, msgs[50])  # duplicated stamp
            msgs[80][1].angular_velocity.x = float("nan")
            for k in (120, 121):  # recorded 0.3 s late: out of order in the log
                msgs[k] = (msgs[k][0] + 300_000_000, msgs[k][1])
            return msgs[:200] + msgs[250:]  # a 0.5 s gap
        if topic == "/wheel/odom":
            msgs = list(msgs)
            msgs[10][1].twist.twist.linear.x = float("nan")
            msgs.insert(20, msgs[20])
            return msgs
        return msgs

    run = run_fuse(FuseJob(fuse_logs.write(w=0.5, duration_s=4.0, wheel_cov=-1.0, edit=edit)))
    imu, wheel = run.metrics["sources"]["imu"], run.metrics["sources"]["wheel"]
    assert {k: v["count"] for k, v in imu["rejected"].items()} == {"nan": 1, "duplicate_stamp": 1}
    assert imu["handled"]["reordered"]["count"] == 2 and imu["handled"]["gaps"]["count"] == 1
    assert {k: v["count"] for k, v in wheel["rejected"].items()} == {"nan": 1, "duplicate_stamp": 1}
    assert wheel["received"] == 82 and wheel["handled"]["default_noise"]["count"] == 80
    # 80 speeds, and the 10 yaw rates inside the IMU's gap (no gyro there to prefer)
    assert wheel["updates"] == 90 and wheel["handled"]["gyro_gap_yaw"]["count"] == 10
    assert run.notes == ["imu: 1 gap in the gyro (the longest 0.5 s): the heading followed the wheels' yaw rate "
                         "(10 messages) and the position the wheels' speed there"]
    err = _errors(fuse_logs, run, 1.0, 0.5)
    gap_ns = fuse_logs.T0_NS + 2 * 10**9  # the IMU is missing from 2.0 to 2.5 s
    assert err[run.trajectory.stamps_ns < gap_ns].max() < 2 * POS_TOL_M
    # no gyro over the gap: the wheels' yaw rate turns the heading there (its 0.25 rad of turn was lost without it)
    assert err.max() < 2 * POS_TOL_M


def test_gps_fixes_enter_and_invalid_ones_are_counted(fuse_logs):
    def edit(topic, msgs):
        if topic == "/gps/fix":
            for k in (3, 7, 11):
                msgs[k][1].status.status = -1
        return msgs

    run = run_fuse(FuseJob(fuse_logs.write(w=0.5, duration_s=6.0, gps_hz=5.0, edit=edit), FuseConfig(smooth=False)))
    gps = run.metrics["sources"]["gps"]  # the planar filter: one update per fix
    assert gps["received"] == 31 and gps["updates"] == 28
    assert gps["rejected"]["no_fix"]["count"] == 3
    assert run.config.input.gps_origin == pytest.approx([47.37, 8.54, 408.0], abs=1e-9)
    assert _errors(fuse_logs, run, 1.0, 0.5).max() < 2 * POS_TOL_M


def test_no_motion_source(fuse_logs):
    log = fuse_logs.write(imu=False, wheel=None, gps_hz=5.0)
    with pytest.raises(InputError) as err:
        run_fuse(FuseJob(log))
    assert gc.isenabled()  # back on after a refused run too
    assert str(err.value) == (f"{log}: no motion source: no IMU or wheel odometry topic found and no odometry given "
                              "(GPS alone cannot be fused); give --odom FILE, --odom-topic, --imu-topic or --wheel-topic")


def test_imu_without_extrinsic_names_its_frame_and_the_fix(fuse_logs):
    log = fuse_logs.write(tf=False, imu_frame="imu_link", duration_s=2.0)
    with pytest.raises(InputError) as err:
        run_fuse(FuseJob(log))
    assert str(err.value) == (f"{log}: IMU /imu is in frame 'imu_link' and neither /tf_static nor --calib gives "
                              "T_base_imu (base_link -> imu_link); pass --calib with T_base_imu (lio calibrate writes one)")
    cfg = FuseConfig(calibration={"T_base_imu": fuse_logs.T_BASE_IMU.tolist()})
    run = run_fuse(FuseJob(log, cfg))
    assert run.metrics["extrinsics"]["T_base_imu"] == "--calib"
    np.testing.assert_allclose(run.trajectory.positions[-1], [2.0, 0.0, 0.0], atol=1e-3)
    assert not any("was not measured" in n for n in run.notes)
    # what lio calibrate writes for a ground robot: the IMU's yaw on the base it could not see, with its 1-sigma
    guessed = FuseConfig(calibration={"T_base_imu": fuse_logs.T_BASE_IMU.tolist(),
                                      "T_base_imu_rotation_sigma_rad": [1e-4, 1e-4, 0.103]})
    assert ("T_base_imu of --calib was not measured about the base z (1-sigma 5.9 deg): the IMU's mounting there is a "
            "guess; give the drawing's value (or /tf_static) if the trajectory turns out wrong") \
        in run_fuse(FuseJob(log, guessed)).notes


def test_gps_without_a_fix(fuse_logs):
    log = fuse_logs.write(gps_hz=5.0, gps_status=-1, duration_s=2.0)
    with pytest.raises(InputError) as err:
        run_fuse(FuseJob(log))
    assert str(err.value) == (f"{log}: topic /gps/fix: no valid fix among its 11 NavSatFix messages (11 without a fix "
                              "(status NO_FIX), 0 with NaN or out-of-range coordinates)")


def test_sources_on_different_clocks_and_the_offset_that_joins_them(fuse_logs):
    log = fuse_logs.write(imu_stamp_shift_ns=1000 * 10**9, duration_s=2.0)
    with pytest.raises(InputError) as err:
        run_fuse(FuseJob(log))
    assert str(err.value) == (
        f"{log}: /imu and /wheel/odom are stamped on different clocks (/imu from 1700001000.000 s, /wheel/odom "
        "from 1700000000.000 s: 1000 s apart beyond their recording times); if /imu runs on a shifted clock give "
        "--imu-time-offset -1000.000; if /wheel/odom does, give --time-offset wheel=1000.000")
    with pytest.raises(InputError) as err:  # an offset given short of the shift: the whole offset is suggested
        run_fuse(FuseJob(log, FuseConfig(calibration={"imu_time_offset_s": -400.0})))
    assert str(err.value).endswith("600 s apart beyond their recording times); if /imu runs on a shifted clock give "
                                   "--imu-time-offset -1000.000; if /wheel/odom does, give --time-offset wheel=600.000")
    # the other way round: the wheels shifted onto the IMU's clock
    run = run_fuse(FuseJob(log, FuseConfig(time_offsets_s={"wheel": 1000.0})))
    np.testing.assert_allclose(run.trajectory.positions[-1], [2.0, 0.0, 0.0], atol=1e-3)
    run = run_fuse(FuseJob(log, FuseConfig(calibration={"imu_time_offset_s": -1000.0})))
    np.testing.assert_allclose(run.trajectory.positions[-1], [2.0, 0.0, 0.0], atol=1e-3)
    assert run.trajectory.stamps_ns[0] == fuse_logs.T0_NS


def test_an_offset_given_to_sources_on_one_clock_is_named(fuse_logs):
    log = fuse_logs.write(duration_s=2.0)
    with pytest.raises(InputError) as err:
        run_fuse(FuseJob(log, FuseConfig(calibration={"imu_time_offset_s": 100.0})))
    assert str(err.value) == (
        f"{log}: /imu and /wheel/odom are stamped on different clocks (/imu from 1700000100.000 s, /wheel/odom "
        "from 1700000000.000 s: 100 s apart beyond their recording times); they agree without the 100.000 s offset "
        "given: give --imu-time-offset 0 or leave it out")


def test_resolved_config_repeats_the_run_exactly(fuse_logs):
    log = fuse_logs.write(w=0.3, duration_s=3.0, gps_hz=5.0)
    first = run_fuse(FuseJob(log, FuseConfig(rate_hz=40.0, smooth=True)))
    again = run_fuse(FuseJob(log, first.config))
    assert again.config == first.config
    np.testing.assert_array_equal(again.trajectory.stamps_ns, first.trajectory.stamps_ns)
    np.testing.assert_array_equal(again.trajectory.poses, first.trajectory.poses)
    assert np.all(first.trajectory.stamps_ns % 25_000_000 == 0)  # 40 Hz on multiples of 25 ms


def test_smoother_and_planar_and_complementary_follow_the_circle(fuse_logs):
    log = fuse_logs.write(w=0.5, duration_s=4.0)
    # the complementary filter has no tilt correction: its accelerometer path would keep the tilt of a start
    # taken while turning, so it runs as the lecture's (gyro heading, wheel speed)
    lecture = {"imu": ["gyro"], "wheel": ["speed"]}
    for cfg in (FuseConfig(smooth=True), FuseConfig(estimator="planar"), FuseConfig(estimator="planar", smooth=True),
                FuseConfig(estimator="complementary", use=lecture)):
        run = run_fuse(FuseJob(log, cfg))
        assert _errors(fuse_logs, run, 1.0, 0.5).max() < 2 * POS_TOL_M, cfg.estimator


def test_covariance_per_pose(fuse_logs):
    run = run_fuse(FuseJob(fuse_logs.write(w=0.5, duration_s=4.0), FuseConfig(rate_hz=10.0), covariance=True))
    cov = run.covariances
    assert cov.shape == (len(run.trajectory), 6, 6)
    np.testing.assert_allclose(cov, np.transpose(cov, (0, 2, 1)), atol=1e-12)
    assert np.all(np.linalg.eigvalsh(cov) > -1e-12)
    pos_var = np.trace(cov[:, :3, :3], axis1=1, axis2=2)
    assert pos_var[-1] > 100 * pos_var[1] > 0  # dead reckoning: the position uncertainty grows
    assert run_fuse(FuseJob(fuse_logs.write(duration_s=1.0))).covariances is None


def test_memory_budget_splits_the_run_into_chunks_that_agree_with_the_whole(fuse_logs):
    log = fuse_logs.write(w=0.2, duration_s=90.0, imu_hz=50, wheel_hz=10)
    whole = run_fuse(FuseJob(log, EKF))  # the filter: the factor graph holds one chunk of its own anyway
    budget = with_overrides(EKF, {"max_memory_mb": 5.0})  # whole ~8.7 MB
    parts = run_fuse(FuseJob(log, budget))
    assert whole.metrics["memory"]["chunks"] == 1 and parts.metrics["memory"]["chunks"] == 3
    for src in ("imu", "wheel"):  # each message once, though the chunks' overlaps read some twice
        assert parts.metrics["sources"][src]["received"] == whole.metrics["sources"][src]["received"]
    np.testing.assert_array_equal(parts.trajectory.stamps_ns, whole.trajectory.stamps_ns)
    assert np.abs(parts.trajectory.positions - whole.trajectory.positions).max() < 0.02
    # 90 s of a noise-free unicycle at 50 Hz: the whole run's discretisation reaches 3.0 cm; the chunks add nothing
    assert _errors(fuse_logs, whole, 1.0, 0.2).max() < 3.5 * POS_TOL_M
    assert _errors(fuse_logs, parts, 1.0, 0.2).max() < _errors(fuse_logs, whole, 1.0, 0.2).max() + 0.001


def test_wheels_and_gps_on_different_clocks_name_the_gps_offset_that_fixes_it(fuse_logs):
    def edit(topic, msgs):
        if topic == "/gps/fix":  # a receiver stamping GPS time, 18 s (leap seconds) off the others
            for _, m in msgs:
                m.header.stamp.sec += 18
        return msgs

    log = fuse_logs.write(gps_hz=5.0, duration_s=2.0, edit=edit)
    with pytest.raises(InputError) as err:
        run_fuse(FuseJob(log))
    assert str(err.value) == (
        f"{log}: /gps/fix and /wheel/odom are stamped on different clocks (/gps/fix from 1700000018.000 s, "
        "/wheel/odom from 1700000000.000 s: 18 s apart beyond their recording times); if /gps/fix runs on a shifted "
        "clock give --time-offset gps=-18.000; if /wheel/odom does, give --time-offset wheel=18.000")
    run = run_fuse(FuseJob(log, FuseConfig(time_offsets_s={"gps": -18.0})))  # the option it names fuses it
    assert run.metrics["sources"]["gps"]["updates"] > 0


def test_a_real_log_fuses_alike_with_the_covariance_symmetrised_at_every_step(real_logs, monkeypatch):
    # the filter symmetrises P only every SYMMETRIZE_EVERY steps when P stays inside it: rounding-level change
    from lio_cli.core.fuse import ekf3d

    job = FuseJob(real_logs / "groovy_imu_wheel_stereo" / "groovy.bag",
                  FuseConfig(calibration={"T_base_imu": np.eye(4).tolist()}))
    sparse = run_fuse(job).trajectory
    monkeypatch.setattr(ekf3d, "SYMMETRIZE_EVERY", 1)
    every = run_fuse(job).trajectory
    assert np.array_equal(sparse.stamps_ns, every.stamps_ns) and len(every) > 10_000
    np.testing.assert_allclose(sparse.poses, every.poses, rtol=0, atol=1e-9)  # measured 4e-13 m


def test_odometry_poses_inside_an_imu_gap_are_taken(fuse_logs):
    """A 1 s IMU gap while turning at 2 rad/s, odometry poses at 20 Hz inside it: the gap was crossed in 20
    hold steps (between the poses) whose rotation noise, cubic in each step's length, summed to 1/400 of one
    step's and ignored the turn rate the gap began with, so 15 poses were rejected as outliers and the fused
    path fell 0.40 m off inside the gap (0.05 m without the gap)."""
    t0 = fuse_logs.T0_NS

    def imu_gap(topic, msgs):
        return [(r, m) for r, m in msgs if topic != "/imu" or not 2 * 10**9 <= r - t0 < 3 * 10**9]

    log = fuse_logs.write(v=1.0, w=2.0, duration_s=5.0, edit=imu_gap)
    cfg = FuseConfig.model_validate({"input": {"odom_topic": "/wheel/odom"}, "rate_hz": 100.0,
                                     "use": {"imu": ["gyro"], "odom": ["pose"]}})
    run = run_fuse(FuseJob(log, cfg))
    odom = run.metrics["sources"]["odom"]
    assert odom["rejected"] == {} and odom["updates"] == 100  # every pose but the anchor
    s = (run.trajectory.stamps_ns - t0) * 1e-9
    assert _errors(fuse_logs, run, 1.0, 2.0)[(s >= 2.0) & (s < 3.0)].max() < 0.1  # 0.052 m; was 0.40 m


def test_a_start_in_a_turn_is_level_with_odometry_poses_or_wheels(fuse_logs):
    """Turning at 2 rad/s and 1 m/s from the first sample: the mean specific force holds 2 m/s^2 of
    centripetal acceleration, and the start took it for gravity (11.5 deg of tilt). With the odometry's poses
    the accelerometer then fought them: 30 poses rejected, 1.90 m off (gyro alone: 0.07 m); with the wheels,
    0.018 m off. The start is now aligned with them: 0.002 m and 0.001 m."""
    log = fuse_logs.write(v=1.0, w=2.0, duration_s=5.0)
    odom = run_fuse(FuseJob(log, FuseConfig.model_validate({"input": {"odom_topic": "/wheel/odom"}, "rate_hz": 100.0,
                                                            "use": {"imu": ["gyro", "accel"], "odom": ["pose"]},
                                                            "smooth": False})))
    assert odom.metrics["sources"]["odom"]["rejected"] == {}
    assert _errors(fuse_logs, odom, 1.0, 2.0).max() < POS_TOL_M
    wheels = run_fuse(FuseJob(log, FuseConfig(rate_hz=100.0, estimator="ekf", smooth=False)))
    assert _errors(fuse_logs, wheels, 1.0, 2.0).max() < POS_TOL_M
    for run, source in ((odom, "odometry"), (wheels, "wheels")):
        up = run.trajectory.poses[0, :3, :3].T @ [0.0, 0.0, 1.0]
        assert up[2] > np.cos(np.radians(0.1))
        assert f"roll, pitch and velocity aligned with the {source} over 41 poses" in run.metrics["start"]


def test_imu_samples_beyond_any_imu_are_dropped_and_counted_or_refused_when_none_is_left(fuse_logs):
    """accel x = 1e300 (what `lio info --check` calls bad): dropped and counted like NaN, without overflow
    warnings; every sample so: the IMU alone cannot run (exit 2)."""
    def some(topic, msgs):
        if topic == "/imu":
            for k in range(10, 60, 5):
                msgs[k][1].linear_acceleration.x = 1e300
        return msgs

    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run = run_fuse(FuseJob(fuse_logs.write(w=0.5, duration_s=2.0, edit=some)))
    assert {k: v["count"] for k, v in run.metrics["sources"]["imu"]["rejected"].items()} == {"out_of_range": 10}
    assert _errors(fuse_logs, run, 1.0, 0.5).max() < 2 * POS_TOL_M

    def every(topic, msgs):
        if topic == "/imu":
            for m in msgs:
                m[1].linear_acceleration.x = 1e300
        return msgs

    with pytest.raises(InputError) as err:
        run_fuse(FuseJob(fuse_logs.write(w=0.5, duration_s=2.0, wheel=None, edit=every)))
    assert str(err.value) == ("the IMU has no usable sample (all NaN, out of range, all zero or duplicated) and "
                              "there is no other motion source")
