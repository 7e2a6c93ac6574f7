"""A ground vehicle's IMU roll and pitch on its base from the planar-motion constraint (GRIL-Calib's idea).

A car or a ground robot on level ground turns about its base's vertical only, so the vertical stays put in
the base frame. Carried along by the gyro through the mounting so far (``R_base_imu``), a vector fixed in the
world, started near the base's vertical, stays within the body's sway of one place; a mounting tilted by
``eps`` (``R_est = exp(eps) R_true``) holds it at ``eps x e_z`` instead of on the axis, while the start's own
error turns with the heading. So, with ``Phi(t)`` the gyro's rotation from the first sample to ``t`` in the
base frame,

    P_xy Phi(t)^T (e_z + d) = w + s(t)

is linear in the start's tilt ``d`` and the constant ``w`` (``eps_x = -w_y``, ``eps_y = w_x``); the sway ``s``
is the residual, and a gyro bias the motion left (three more unknowns, their effect linearised) drifts it.
The heading must change for ``d`` and ``w`` to part: a straight drive leaves them together. Nothing here needs
the LiDAR, the wheels or the accelerometer (whose horizontal bias would read as tilt: 0.04 m/s^2 is 0.23 deg).
The 1-sigma is residual-scaled (sandwich over neighbouring samples: sway is slow), never assumed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from .common import NS_PER_S, CalibrationResult, sandwich_covariance
from .signals import GyroOrientation

SAMPLE_S = 0.1  # the gyro's orientation is read this often
LAG_S = 3.0  # sway this slow is shared by neighbouring samples (the sandwich's lag)
MIN_SAMPLES = 50
MAX_SWAY_RAD = np.radians(2.0)  # rms residual above which the motion is not planar (a hand-held sweep, a ramp)
BIAS_STEP_RADPS = 1e-4  # the bias's linearisation step


@dataclass(frozen=True, eq=False)
class PlanarTilt(CalibrationResult):
    tilt_rad: np.ndarray  # (2,) eps about the base x, y: R_base_imu -> exp(-eps) R_base_imu corrects it
    covariance_rad2: np.ndarray  # (2,2)
    sigma_rad: np.ndarray  # (2,)
    heading_spread_rad: float  # max - min of the heading over the samples
    rms_sway_rad: float  # of the residual
    samples: int
    notes: tuple[str, ...]


def estimate_planar_tilt(imu_stamps_ns: np.ndarray, gyro_radps: np.ndarray, *, R_base_imu: np.ndarray,
                         gyro_bias_radps: np.ndarray | None = None, max_sway_rad: float = MAX_SWAY_RAD) -> PlanarTilt:
    """Roll and pitch error of ``R_base_imu`` (maps IMU vectors into the base frame) from the gyro of a vehicle
    turning about its base z (see the module). InputError when the samples are too few or the motion is not
    planar (the residual sway's rms above ``max_sway_rad``)."""
    s = np.asarray(imu_stamps_ns, np.int64)
    gyro = np.asarray(gyro_radps, float)
    if len(s) < 10 or (s[-1] - s[0]) / NS_PER_S < MIN_SAMPLES * SAMPLE_S:
        raise InputError(f"roll and pitch from planar motion: {(s[-1] - s[0]) / NS_PER_S if len(s) else 0:.1f} s of "
                         f"gyro (need {MIN_SAMPLES * SAMPLE_S:g})")
    Rbi = np.asarray(R_base_imu, float)
    b0 = np.zeros(3) if gyro_bias_radps is None else np.asarray(gyro_bias_radps, float)
    t = np.arange(0.0, (s[-1] - s[0]) / NS_PER_S, SAMPLE_S)

    def up_columns(bias: np.ndarray) -> np.ndarray:  # (n, 3, 3): Phi(t)^T in the base frame
        G = GyroOrientation(s, gyro, bias).at(t)
        return Rbi @ np.transpose(G, (0, 2, 1)) @ Rbi.T

    Phi = up_columns(b0)
    base = Phi[:, :2, 2]  # P_xy Phi^T e_z
    cols = [Phi[:, :2, 0], Phi[:, :2, 1], -np.tile(np.eye(2)[0], (len(t), 1)), -np.tile(np.eye(2)[1], (len(t), 1))]
    for k in range(3):  # a bias left in the gyro: its effect on P_xy Phi^T e_z, per unit
        db = np.zeros(3)
        db[k] = BIAS_STEP_RADPS
        cols.append((up_columns(b0 + db)[:, :2, 2] - base) / BIAS_STEP_RADPS)
    J = np.stack(cols, axis=2)  # (n, 2, 7): d_x, d_y, w_x, w_y, bias x3
    A = J.reshape(-1, J.shape[2])
    y = -base.reshape(-1)
    scale = np.ones(A.shape[1])
    scale[4:] = 1e-3  # the bias's columns are large (rad per rad/s): keep the solve well conditioned
    x = np.linalg.lstsq(A * scale, y, rcond=None)[0] * scale
    r = (y - A @ x).reshape(-1, 2)
    rms = float(np.sqrt((r * r).sum(axis=1).mean()))
    heading = np.unwrap(np.arctan2(Phi[:, 1, 0], Phi[:, 0, 0]))
    spread = float(heading.max() - heading.min())
    if rms > max_sway_rad:
        raise InputError(f"roll and pitch from planar motion: the vertical moves {np.degrees(rms):.1f} deg rms in the "
                         f"base frame (at most {np.degrees(max_sway_rad):g}): the platform does not turn about its "
                         "base z only (not a ground vehicle on level ground, or the base frame is not on the ground)")
    H = A.T @ A
    scores = np.einsum("nji,nj->ni", J, r)
    cov = sandwich_covariance(H, scores, lag=max(1, int(round(LAG_S / SAMPLE_S))))
    # eps = (-w_y, w_x): w = eps x e_z
    M = np.array([[0.0, -1.0], [1.0, 0.0]])
    tilt = M @ x[2:4]
    C = M @ cov[2:4, 2:4] @ M.T
    return PlanarTilt(tilt_rad=tilt, covariance_rad2=C, sigma_rad=np.sqrt(np.clip(np.diag(C), 0, None)),
                      heading_spread_rad=spread, rms_sway_rad=rms, samples=len(t), notes=())
