"""``lio deskew``: the job, the motion source, per-scan de-skew, the writer and its helper process."""
