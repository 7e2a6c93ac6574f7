"""``lio deskew``'s configuration: everything a run needs besides the log, the output and the map file.

The ``.config.yaml`` a run writes is this model after resolution (topics, base frame and motion source filled
in), so ``lio deskew LOG OUT --config that.config.yaml`` repeats the run exactly. The input and output formats
stay as asked (None: detected from the log, OUT's suffix): a format found for one log must not bind another.
"""

from __future__ import annotations

import re
from typing import Literal, Optional

from pydantic import Field, create_model, field_validator

from ..model.calibration import Calibration
from . import MAX_EVERY, MAX_ITERATIONS, Strict
from .odom import FusionConfig, InputConfig, OdomConfig, RegistrationConfig

MOTIONS = ("auto", "trajectory", "imu", "constant-velocity")
OUTPUT_FORMATS = ("ros1", "ros2", "ros2-mcap", "mcap")


class TrajectoryInput(Strict):
    """A trajectory that gives the motion (``--trajectory``)."""

    path: Optional[str] = Field(None, description="TUM file or LOG:/topic (a pose topic of a log); e.g. the output of lio odom")
    frame: Literal["base", "lidar"] = Field("base", description="the frame whose poses the trajectory holds")
    interpolation: Literal["cubic", "linear"] = Field(
        "cubic", description="cubic through the 4 nearest poses, or SE(3) interpolation between the 2 nearest")
    max_gap_s: float = Field(0.5, gt=0, description="a sweep within a longer gap between poses counts as not covered")


# The in-process odometry (motion imu or constant-velocity) takes these fields of lio odom's configuration;
# input, calibration, prior and deskew come from the deskew configuration.
_ODOMETRY_FIELDS = ("use_wheel", "planar", "init_window_s", "max_gap_s", "max_bridge_s", "max_lost_scans",
                    "estimate_time_offset", "max_speed_mps", "gravity_mps2")


class DeskewRegistration(RegistrationConfig):
    """lio odom's registration settings, but ICP stops early where the IMU prediction can be leant on (2
    iterations below 10 deg/s, 5 once the IMU clock is timed) and registers every second slowly turning scan.
    10 deg/s: the online clock estimate cannot time a slower stretch, so full iterations there buy it nothing.
    Defaults of this class, so a YAML naming other registration fields keeps them."""

    steady_iterations: Optional[int] = Field(5, gt=0, le=MAX_ITERATIONS, description=RegistrationConfig.model_fields[
        "steady_iterations"].description)
    slow_iterations: Optional[int] = Field(2, gt=0, le=MAX_ITERATIONS, description=RegistrationConfig.model_fields[
        "slow_iterations"].description)
    slow_rate_degps: float = Field(10.0, ge=0, description=RegistrationConfig.model_fields[
        "slow_rate_degps"].description)
    slow_register_every: int = Field(2, ge=1, le=4, description=RegistrationConfig.model_fields[
        "slow_register_every"].description)


class DeskewFusion(FusionConfig):
    """lio odom's fusion settings, but the geometry of a scene far from degenerate (an open road) is analysed
    every 8th scan instead of every 2nd. A default of this class, so a YAML naming other fusion fields keeps it."""

    degeneracy_every_clear: int = Field(8, ge=1, le=MAX_EVERY, description=FusionConfig.model_fields[
        "degeneracy_every_clear"].description)


OdometryPass = create_model(
    "OdometryPass", __base__=Strict, __doc__="Settings of the odometry run in-process (as lio odom's fields).",
    **{name: (OdomConfig.model_fields[name].annotation, OdomConfig.model_fields[name]) for name in _ODOMETRY_FIELDS},
    registration=(DeskewRegistration, DeskewRegistration()),
    fusion=(DeskewFusion, DeskewFusion()),
)


class DeskewConfig(Strict):
    """Everything ``lio deskew`` can be told; flags override the YAML field by field."""

    input: InputConfig = InputConfig()
    calibration: Calibration = Field(Calibration(), description="used where /tf_static is silent (see --calib)")
    motion: Literal["auto", "trajectory", "imu", "constant-velocity"] = Field(
        "auto", description="auto: trajectory when one is given, else imu when the log has an IMU")
    trajectory: TrajectoryInput = TrajectoryInput()
    reference: Literal["end", "start"] = Field("end", description="the instant each cloud is de-skewed to")
    output_format: Optional[Literal["ros1", "ros2", "ros2-mcap", "mcap"]] = Field(
        None, description="default: from OUT's suffix (.bag ros1, .mcap mcap), else the input's")
    topic_suffix: Optional[str] = Field(None, description="write de-skewed clouds to TOPIC+suffix, keep the raw ones")
    strict: bool = Field(False, description="refuse a scan the motion does not cover, or without a valid point or "
                         "sweep, instead of copying it unchanged")
    map_voxel_m: float = Field(0.1, gt=0, description="voxel size of --map")
    odometry: OdometryPass = OdometryPass()

    @field_validator("topic_suffix")
    @classmethod
    def _suffix(cls, v: str | None) -> str | None:
        if v is not None and not re.fullmatch(r"[A-Za-z0-9_/]+", v):
            raise ValueError(f"'{v}' is not a topic-name suffix (letters, digits, _ and / only, e.g. _deskewed)")
        return v

    def odom_config(self, motion: str) -> OdomConfig:
        """The configuration of the in-process odometry for ``motion`` (imu or constant-velocity)."""
        return OdomConfig.model_validate({
            "input": self.input.model_dump(), "calibration": self.calibration.model_dump(), "prior": motion,
            "deskew": motion, "scan_reference": "end", "frame": "base", **self.odometry.model_dump(),
        })


__all__ = ["DeskewConfig", "MOTIONS", "OUTPUT_FORMATS", "OdometryPass", "TrajectoryInput"]
