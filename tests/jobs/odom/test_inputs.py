"""``jobs.odom.inputs``: which mounting a run takes when the log's /tf_static and ``--calib`` both give one, and
the note that says how far apart they are."""

import numpy as np
import pytest

from lio_cli.geometry import make_pose, so3_exp
from lio_cli.io.sensors.tf import FrameTree
from lio_cli.model.calibration import Calibration
from lio_cli.model.records import TransformRecord
from lio_cli.jobs.odom.inputs import Mounting, mounting_apart

T_TF = make_pose(so3_exp(np.array([0.0, 0.0, np.pi / 2])), np.array([0.04, -0.02, 0.03]))
# the file's: 3 cm further along x and 2 deg more about z
T_FILE = make_pose(so3_exp(np.array([0.0, 0.0, np.pi / 2 + np.radians(2.0)])), np.array([0.07, -0.02, 0.03]))


def _mounting(calibration: Calibration, notes: list[str]) -> Mounting:
    tree = FrameTree([TransformRecord(0, "base", "imu", T_TF)])
    return Mounting.of(tree, calibration, None, notes)


def test_mounting_apart_is_translation_and_rotation_angle():
    dt, dr = mounting_apart(T_TF, T_FILE)
    assert dt == pytest.approx(0.03, abs=1e-12)
    assert np.degrees(dr) == pytest.approx(2.0, abs=1e-9)


@pytest.mark.parametrize("prefer", [False, True])
def test_both_give_it_a_note_says_how_far_apart_and_prefer_file_chooses(prefer):
    notes: list[str] = []
    m = _mounting(Calibration(T_base_imu=T_FILE.tolist(), prefer_file=prefer), notes)
    T = m.resolve("T_base_imu", "imu")
    np.testing.assert_array_equal(T, T_FILE if prefer else T_TF)
    used = "--calib's (--prefer-calib)" if prefer else "the log's (--prefer-calib uses --calib's)"
    assert notes == [f"T_base_imu: /tf_static (base -> imu) and --calib are 3.00 cm and 2.000 deg apart; using {used}"]
    assert m.sources["T_base_imu"] == ("--calib (--prefer-calib; the log has /tf_static (base -> imu))" if prefer
                                       else "/tf_static (base -> imu)")


def test_the_same_mounting_twice_says_nothing():
    notes: list[str] = []
    m = _mounting(Calibration(T_base_imu=T_TF.tolist()), notes)
    np.testing.assert_array_equal(m.resolve("T_base_imu", "imu"), T_TF)
    assert notes == []


def test_prefer_file_without_the_extrinsic_in_the_file_keeps_the_log_s():
    notes: list[str] = []
    m = _mounting(Calibration(prefer_file=True), notes)
    np.testing.assert_array_equal(m.resolve("T_base_imu", "imu"), T_TF)
    assert notes == [] and m.sources["T_base_imu"] == "/tf_static (base -> imu)"
