"""What ``lio calibrate`` says about axes it measured, but not precisely: which, how precisely, and the motion
that would show them better."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from lio_cli.geometry import make_pose, so3_exp
from lio_cli.jobs.calibrate.report import imprecision_notes


def _poses(axes: np.ndarray) -> np.ndarray:
    """A trajectory turning by 0.1 rad per step about each of ``axes`` in turn."""
    R, out = np.eye(3), []
    for a in axes:
        R = R @ so3_exp(0.1 * np.asarray(a, float))
        out.append(make_pose(R, np.zeros(3)))
    return np.stack(out)


def _estimates(rot_sigma_deg, lever_sigma_cm) -> SimpleNamespace:
    rc = np.diag(np.radians(rot_sigma_deg) ** 2)
    lever = SimpleNamespace(rotation_covariance_rad2=rc, rotation_sigma_rad=np.sqrt(np.diag(rc)),
                            sigma_m=np.asarray(lever_sigma_cm) / 100,
                            observable=np.asarray(lever_sigma_cm) <= 5.0)
    return SimpleNamespace(rotation=SimpleNamespace(covariance_rad2=rc, observable=np.asarray(rot_sigma_deg) <= 1.0),
                           lever=lever)


def test_a_walk_turning_about_the_vertical_is_told_to_tilt_and_a_short_log_to_record_longer():
    est = _estimates([0.1, 0.15, 0.46], [0.7, 0.8, 4.0])
    yaw_mostly = _poses([(0, 0, 1)] * 40 + [(1, 0, 0), (0, 1, 0)] * 2)
    assert imprecision_notes(est, yaw_mostly) == [
        "the mounting's rotation about the LiDAR z axis is measured to 1-sigma 0.46 deg only: the platform turned "
        "mostly about that axis (91% of its rotation): tilt and roll the sensor (+-10-20 deg) while recording (a "
        "vehicle: drive over ramps and bumps)",
        "the lever arm along the LiDAR z axis is measured to 1-sigma 4.0 cm only: the platform turned mostly about "
        "that axis (91% of its rotation): tilt and roll the sensor (+-10-20 deg) while recording (a vehicle: drive "
        "over ramps and bumps)",
    ]
    every_axis = _poses([(1, 0, 0), (0, 1, 0), (0, 0, 1)] * 10)
    assert imprecision_notes(est, every_axis)[0].endswith(
        "0.46 deg only: record longer (a minute or more) or turn the sensor more briskly about the other axes")


def test_precise_or_unobservable_axes_get_no_such_note():
    # within 0.2 deg / 2 cm: nothing to say; beyond the observable limits: the skipped lines say it instead
    assert imprecision_notes(_estimates([0.1, 0.15, 0.19], [0.7, 0.8, 1.9]), _poses([(0, 0, 1)] * 10)) == []
    assert imprecision_notes(_estimates([0.1, 0.15, 3.0], [0.7, 0.8, 12.0]), _poses([(0, 0, 1)] * 10)) == []
