"""``lio calibrate``: odometry passes, the estimators in order, the map refinement, the report."""
