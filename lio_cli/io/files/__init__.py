"""Files that are not logs: atomic outputs, output paths, trajectory text formats, point clouds, Kalibr YAML."""
