"""A log fused in pieces (``lio fuse --max-memory``): what is decided once over the whole log and handed to
every piece, so a piece does not decide it again from its own shorter data.

``CheckedWheels``: the whole log's wheel check (``wheel_slip``: scale, slips bridged, the verdict), applied to a
piece's wheel samples by stamp. The check works on per-sample arrays (a few floats per IMU and wheel sample), so
the whole log's costs little beside the estimators' records.

``handover``: a piece's estimated state where the next piece starts (attitude, velocity, gyro bias and their
sigmas), that piece's ``Start`` in place of one found again from its own first second (a moving start knows no
gyro bias, and nothing but a standing start measures the planar filter's).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...geometry import so3_exp_one
from .initial import Start
from .inputs import WheelSeries
from .planar_model import BW, TH, V
from .timeline import Prepared


@dataclass(frozen=True)
class CheckedWheels:
    """The wheels as the whole log's check left them, by stamp (``FuseOptions.wheel_check``)."""

    check: dict  # wheel_slip.SlipReport.to_dict()
    stamps_ns: np.ndarray  # the checked samples (a finite forward speed)
    speed_mps: np.ndarray  # their forward speed after the check (scaled, slips bridged)
    var_factor: float  # the scale squared: multiplies the forward speed's variance
    spans_ns: tuple[tuple[int, int, bool], ...]  # each slip's first and last stamp, and whether it was bridged

    @classmethod
    def of(cls, checked: WheelSeries, report) -> CheckedWheels:
        """From the wheels ``wheel_slip.check_wheels`` left in the whole log's ``Prepared`` and its report."""
        ok = np.isfinite(checked.velocity_mps[:, 0])
        scale = report.scale if report.scale_applied else 1.0
        return cls(report.to_dict(), checked.stamps_ns[ok], checked.velocity_mps[ok, 0].copy(), scale**2,
                   tuple(report.spans_ns))

    def apply(self, prep: Prepared) -> dict:
        """Put the checked speeds into ``prep.wheel`` where the stamps match, count the piece's notes as
        ``check_wheels`` does, and return the whole log's check (for ``prep.wheel_check``)."""
        w = prep.wheel
        ok = np.isfinite(w.velocity_mps[:, 0])
        i = np.minimum(np.searchsorted(self.stamps_ns, w.stamps_ns), len(self.stamps_ns) - 1)
        seen = ok & (self.stamps_ns[i] == w.stamps_ns)
        vel = w.velocity_mps.copy()
        vel[seen, 0] = self.speed_mps[i[seen]]
        var = None
        if w.velocity_var is not None:
            var = w.velocity_var.copy()
            var[seen, 0] *= self.var_factor
        prep.wheel = replace(w, velocity_mps=vel, velocity_var=var)
        report = prep.reports["wheel"]
        for bridged, note in ((True, "slip_bridged"), (False, "slip_left_in")):
            inside = np.zeros(len(w), bool)
            for a, b, kind in self.spans_ns:
                if kind == bridged:
                    inside |= (w.stamps_ns >= a) & (w.stamps_ns <= b)
            report.note(note, int(np.count_nonzero(seen & inside)))
        if self.check.get("scale_applied"):
            report.note("scale_corrected", int(np.count_nonzero(seen)))
        return self.check


def planar_handover(t_ns: np.ndarray, x: np.ndarray, P: np.ndarray, at_ns: int) -> Start:
    """The planar filter's state (``x``, ``P`` at knots ``t_ns``) at the first knot from ``at_ns`` on, as a
    ``Start`` in this piece's world."""
    k = min(int(np.searchsorted(t_ns, at_ns)), len(t_ns) - 1)
    R = so3_exp_one(np.array([0.0, 0.0, float(x[k, TH])]))
    return Start(R, R @ np.array([x[k, V], 0.0, 0.0]), np.array([0.0, 0.0, x[k, BW]]),
                 float(np.sqrt(P[k, V, V])), float(np.sqrt(P[k, BW, BW])), False, "handover",
                 f"handed over by the chunk before: speed {x[k, V]:.2f} m/s, gyro z bias {x[k, BW]:.5f} rad/s",
                 float(np.sqrt(P[k, TH, TH])))


def state_handover(t_ns: np.ndarray, states: dict[str, np.ndarray], at_ns: int, v_sigma_mps: float,
                   bg_sigma_radps: float) -> Start:
    """The 3D state (``R``, ``v``, ``bg``, ``ba`` per stamp of ``t_ns``: the graph's keyframes or the 3D filter's
    knots) at the first stamp from ``at_ns`` on, as a ``Start`` in this piece's world (loose velocity and gyro
    bias sigmas: the next piece's IMU, wheels and GPS find them again)."""
    k = min(int(np.searchsorted(t_ns, at_ns)), len(t_ns) - 1)
    v, bg = states["v"][k].copy(), states["bg"][k].copy()
    start = Start(states["R"][k].copy(), v, bg, v_sigma_mps, bg_sigma_radps, False, "handover",
                  f"handed over by the chunk before: speed {np.linalg.norm(v):.2f} m/s, gyro bias "
                  f"{np.linalg.norm(bg):.5f} rad/s")
    start.ba = states["ba"][k].copy()
    return start


def turned_handover(start: Start | None, R: np.ndarray) -> Start | None:
    """A handed-over state carried by the world rotation ``R`` (a track placed on the GPS fixes)."""
    return None if start is None else replace(start, R=R @ start.R, v=R @ start.v)


__all__ = ["CheckedWheels", "planar_handover", "state_handover", "turned_handover"]
