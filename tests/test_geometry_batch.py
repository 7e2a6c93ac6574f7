"""The scipy-free rotation helpers (``so3_exp``, ``so3_log``, ``so3_log_batch``, ``quat_xyzw_to_rot``) against
scipy itself, and ``row_norms`` against numpy's norm, which they replace on hot paths."""

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lio_cli.geometry import cross_rows, quat_xyzw_to_rot, row_norms, so3_exp, so3_log, so3_log_batch

ULP_RAD = 1e-15  # scipy and the numpy port differ by at most a unit or two in the last place (of values <= pi)


def _matrices() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    axes = rng.normal(size=(2000, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    return {
        "random": Rotation.random(5000, random_state=8).as_matrix(),
        "tiny": Rotation.from_rotvec(rng.normal(0, 1e-5, (2000, 3))).as_matrix(),
        "near pi": Rotation.from_rotvec(axes * (np.pi - rng.uniform(0, 1e-7, (2000, 1)))).as_matrix(),
        "not orthogonal": Rotation.random(2000, random_state=9).as_matrix() + rng.normal(0, 1e-8, (2000, 3, 3)),
        "identity": np.repeat(np.eye(3)[None], 3, axis=0),
    }


@pytest.mark.parametrize("name", list(_matrices()))
def test_so3_log_batch_is_scipys_rotvec(name):
    R = _matrices()[name]
    ours, theirs = so3_log_batch(R), Rotation.from_matrix(R).as_rotvec()
    assert np.abs(ours - theirs).max() <= ULP_RAD
    assert np.abs(so3_log_batch(R[0]) - so3_log(R[0])).max() <= ULP_RAD  # one matrix in, one vector out


# so3_exp and so3_log are scipy's algorithms operation for operation: on x86-64 Linux they give scipy's bits
# (numpy's sin and cos are the C library's there); elsewhere a last bit may differ, which is all these allow.
@pytest.mark.parametrize("name", list(_matrices()))
def test_so3_log_is_scipys_rotvec(name):
    R = _matrices()[name]
    assert np.abs(so3_log(R) - Rotation.from_matrix(R).as_rotvec()).max() <= ULP_RAD
    assert np.abs(so3_log(R[1]) - Rotation.from_matrix(R[1]).as_rotvec()).max() <= ULP_RAD


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-5, 9.9e-4, 1e-3, 1.1e-3, 0.05, 1.0, 3.0, np.pi])
def test_so3_exp_is_scipys_matrix(scale):
    v = np.random.default_rng(6).normal(size=(3000, 3))
    v *= scale / np.linalg.norm(v, axis=1)[:, None] * np.random.default_rng(7).uniform(0.5, 1.5, (len(v), 1))
    assert np.abs(so3_exp(v) - Rotation.from_rotvec(v).as_matrix()).max() <= 4e-16
    assert np.abs(so3_exp(v[2]) - Rotation.from_rotvec(v[2]).as_matrix()).max() <= 4e-16


def test_rotations_do_not_import_scipy():
    code = ("import sys, numpy as np; from lio_cli.geometry import so3_exp, so3_log; "
            "so3_log(so3_exp(np.array([0.1, 0.2, 0.3]))); print('scipy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_so3_log_batch_refuses_reflections_as_scipy_does():
    with pytest.raises(ValueError, match="Non-positive determinant"):
        so3_log_batch(np.stack([np.eye(3), np.diag([1.0, 1.0, -1.0])]))


def test_quat_to_rot_is_scipys_and_normalises():
    q = np.random.default_rng(3).normal(size=(3000, 4))  # not unit length
    assert np.array_equal(quat_xyzw_to_rot(q), Rotation.from_quat(q).as_matrix())
    assert np.array_equal(quat_xyzw_to_rot(q[0]), Rotation.from_quat(q[0]).as_matrix())
    with pytest.raises(ValueError, match="zero norm"):
        quat_xyzw_to_rot(np.zeros(4))


def test_row_norms_equal_numpys_to_the_bit():
    v = np.random.default_rng(4).normal(0, 30, (16384, 3))
    assert np.array_equal(row_norms(v), np.linalg.norm(v, axis=1))
    assert np.array_equal(row_norms(v[::3]), np.linalg.norm(v[::3], axis=1))


def test_cross_rows_equal_numpys_to_the_bit():
    rng = np.random.default_rng(9)
    a, b, r = rng.normal(size=(500, 3)), rng.normal(size=(500, 3)), rng.normal(size=3)
    assert np.array_equal(cross_rows(a, b), np.cross(a, b))
    assert np.array_equal(cross_rows(a, r), np.cross(a, r))
    assert np.array_equal(cross_rows(a, cross_rows(a, r)), np.cross(a, np.cross(a, r)))
