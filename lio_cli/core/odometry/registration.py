"""Scan registration: kiss-icp's voxel map and ICP, driven with our own initial guesses.

The only module that imports kiss_icp, and only through its public Python API (config, map, registration,
threshold estimator, voxelisation).
"""

from __future__ import annotations

import math

import numpy as np
from kiss_icp.config import KISSConfig
from kiss_icp.mapping import VoxelHashMap
from kiss_icp.registration import get_registration
from kiss_icp.threshold import get_threshold_estimator
from kiss_icp.voxelization import voxel_down_sample

from ...config.odom import RegistrationConfig

_IMU_PRIOR_ITERATIONS = 20
_KISS_ITERATIONS = 500
_SOURCE_FACTOR = 2.5  # sparser registered points than kiss-icp's 1.5: faster for a little accuracy
_PLANAR_SOURCE_FACTOR = 1.5  # kiss-icp's own default, for 2D scans


class ScanRegistration:
    """A local voxel map and the registration of de-skewed scans against it.

    ``fixed_correspondence_m``: with a good prior (the IMU prediction is within centimetres) correspondences
    are gated at this distance and ICP stops after few iterations; None keeps kiss-icp's adaptive threshold.
    """

    def __init__(self, rc: RegistrationConfig, voxel_size_m: float, *, imu_prior: bool, planar: bool,
                 fixed_correspondence_m: float | None) -> None:
        self.voxel_size_m = voxel_size_m
        # a dense 3D scan keeps enough structure at 2.5 voxels; a 2D scan's few hundred beams do not
        self.source_factor = rc.source_voxel_factor or (_PLANAR_SOURCE_FACTOR if planar else _SOURCE_FACTOR)
        self.max_source_points = rc.max_source_points
        # a coarse-to-fine ICP where an IMU prediction starts it (never with kiss-icp's own iterations)
        self.coarse_points = rc.coarse_points if imu_prior else None
        self.refine_iterations = rc.refine_iterations
        kiss = KISSConfig()
        kiss.data.max_range = rc.max_range_m
        kiss.mapping.voxel_size = voxel_size_m
        kiss.mapping.max_points_per_voxel = rc.max_points_per_voxel
        kiss.registration.max_num_iterations = rc.max_iterations or (_IMU_PRIOR_ITERATIONS if imu_prior else _KISS_ITERATIONS)
        kiss.registration.convergence_criterion = rc.convergence
        kiss.registration.max_num_threads = rc.threads
        kiss.adaptive_threshold.initial_threshold = rc.initial_threshold_m
        kiss.adaptive_threshold.min_motion_th = rc.min_motion_m
        # kiss-icp gates correspondences at 3 sigma with a kernel of sigma: a fixed gate g is sigma = g / 3
        kiss.adaptive_threshold.fixed_threshold = None if fixed_correspondence_m is None else fixed_correspondence_m / 3.0
        self.map = VoxelHashMap(voxel_size_m, rc.max_range_m, rc.max_points_per_voxel)
        self._registration = get_registration(kiss)
        self._threshold = get_threshold_estimator(kiss)
        # without a good prior (start-up window, recovery): kiss-icp's own adaptive gate and iterations
        wide = kiss.model_copy(deep=True)
        wide.adaptive_threshold.fixed_threshold = None
        wide.registration.max_num_iterations = rc.max_iterations or _KISS_ITERATIONS
        self._wide_registration = get_registration(wide)
        self._kiss = kiss
        self._capped: dict[int, object] = {}  # iterations -> registration (where the IMU prediction is leant on)
        self._adaptive = get_threshold_estimator(wide)
        self.scans = 0  # scans added to the map

    @property
    def empty(self) -> bool:
        return self.map.empty()

    def downsample(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(points kept for the map, sparser points registered), as kiss-icp's double voxelisation; with
        ``max_source_points``, registered points past it are thinned again with voxels grown by the square root of
        the excess (the points lie on surfaces: their count falls with the voxel's area)."""
        frame = voxel_down_sample(points, self.voxel_size_m * 0.5)
        voxel = self.voxel_size_m * self.source_factor
        source = voxel_down_sample(frame, voxel)
        cap = self.max_source_points
        if cap is not None and len(source) > cap:
            source = voxel_down_sample(frame, voxel * math.sqrt(len(source) / cap))
        return frame, source

    def register(self, source: np.ndarray, guess: np.ndarray, adaptive: bool = False,
                 gate_m: float | None = None, iterations: int | None = None) -> np.ndarray:
        """T_world_base that best aligns ``source`` (base frame) to the map, starting from ``guess``.

        ``adaptive``: the guess may be coarse, so kiss-icp's full iterations are used, with correspondences
        gated at ``gate_m`` or, when None, by kiss-icp's adaptive threshold. ``iterations``: at most this many
        (an IMU prediction good enough to lean on), else the configured maximum.
        """
        if self.map.empty():
            return guess
        if adaptive:
            sigma = self._adaptive.get_threshold() if gate_m is None else gate_m / 3.0
            return self._wide_registration.align_points_to_map(source, self.map, guess, 3.0 * sigma, sigma)
        sigma = self._threshold.get_threshold()
        reg = self._registration if iterations is None else self._capped_registration(iterations)
        coarse, refine = self.coarse_points, self.refine_iterations
        if coarse is not None and len(source) > 2 * coarse and (iterations is None or iterations > refine):
            # ICP costs points x iterations: most iterations on a sparser copy, the last few on every point (a cap
            # of at most refine_iterations, as lio deskew's, already is that few)
            sparse = voxel_down_sample(source, self.voxel_size_m * self.source_factor * math.sqrt(len(source) / coarse))
            guess = reg.align_points_to_map(sparse, self.map, guess, 3.0 * sigma, sigma)
            reg = self._capped_registration(refine)
        return reg.align_points_to_map(source, self.map, guess, 3.0 * sigma, sigma)

    def _capped_registration(self, iterations: int):
        if iterations >= self._kiss.registration.max_num_iterations:  # a cap never adds iterations
            return self._registration
        reg = self._capped.get(iterations)
        if reg is None:
            kiss = self._kiss.model_copy(deep=True)
            kiss.registration.max_num_iterations = iterations
            reg = self._capped[iterations] = get_registration(kiss)
        return reg

    def accept(self, correction: np.ndarray | None, frame: np.ndarray, pose: np.ndarray) -> None:
        """Feed the registration's deviation from its guess to the threshold models and add ``frame`` at ``pose``."""
        if correction is not None:
            self._threshold.update_model_deviation(correction)
            self._adaptive.update_model_deviation(correction)
        self.map.update(frame, pose)
        self.scans += 1



def auto_voxel_size(ranges_m: np.ndarray) -> float:
    """Map voxel size from the first scan: ~1% of the far ranges (kiss-icp's rule), within [0.5, 1.0] m."""
    far = float(np.percentile(ranges_m, 95)) if len(ranges_m) else 100.0
    return float(np.clip(far / 40.0, 0.5, 1.0))
