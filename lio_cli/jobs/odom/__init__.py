"""``lio odom``: the job, its inputs (topics, extrinsics, clocks) and its run."""
