"""``lio calibrate``: the job, its odometry passes, the estimators in order, the map rounds and the report.

``COMMAND``: ``CalibrateJob`` -> ``run_calibrate`` -> ``write_calibrate``.
"""

from ...config.calibrate import CalibrateConfig
from ..contract import Command
from .job import TAG, CalibrateJob, CalibrateResult, check_calibrate_outputs, run_calibrate, write_calibrate, yaml_text

COMMAND = Command(
    name="calibrate", config=CalibrateConfig, job=lambda log, config, out: CalibrateJob(log, out, config),
    run=run_calibrate, write=write_calibrate, score=None, tag=TAG,
    output=lambda folder, log, config: folder / f"{TAG}.yaml",
    key_metrics=lambda metrics: {},  # its figures are the calibration itself, in the run's calib.yaml
    threads=lambda config: config.registration.threads,
    calibration_field="prior",  # a calibration given to calibrate is the reference it compares with
)

__all__ = ["COMMAND", "TAG", "CalibrateJob", "CalibrateResult", "check_calibrate_outputs", "run_calibrate",
           "write_calibrate", "yaml_text"]
