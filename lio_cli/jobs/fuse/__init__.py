"""``lio fuse``: inputs from a log and files, the fusion in chunks, the outputs."""
