"""``io.files.output_paths``: the one rule naming the files a command writes beside its main output."""

from pathlib import Path

import pytest

from lio_cli.io.files.output_paths import side_file, tagged_name


@pytest.mark.parametrize(("out", "tag", "want"), [
    ("walk.tum", "odom", "walk.odom"),  # the tag added
    ("walk.odom.tum", "odom", "walk.odom"),  # already there: once only
    ("odom.tum", "odom", "odom"),  # a batch run's folder: the tag alone
    ("walk.calib.yaml", "calib", "walk.calib"),
    ("walk_deskewed.bag", "deskew", "walk_deskewed.deskew"),
    ("walk_ros2", "deskew", "walk_ros2.deskew"),  # a ROS 2 bag folder has no suffix
    ("walk.fused.tum", "fuse", "walk.fused.fuse"),  # another word is not the tag
    ("my.odometry.tum", "odom", "my.odometry.odom"),
])
def test_the_tag_appears_once(out, tag, want):
    assert tagged_name(Path(out), tag) == want


def test_side_files_of_different_commands_never_share_a_name(tmp_path):
    """The flow that collided: simulate's, odom's, deskew's and calibrate's files of one log ``walk``."""
    names = [side_file(tmp_path / out, tag, suffix)
             for out, tag in (("walk.bag", "sim"), ("walk.tum", "odom"), ("walk.odom.tum", "odom"),
                              ("walk.fuse.tum", "fuse"), ("walk.calib.yaml", "calib"), ("walk.bag", "deskew"))
             for suffix in (".metrics.json", ".config.yaml")]
    assert names[2:4] == names[4:6]  # -o walk.tum and -o walk.odom.tum: one run's names
    distinct = names[:4] + names[6:]
    assert len(set(distinct)) == len(distinct)
    assert side_file(tmp_path / "sub" / "walk.tum", "odom", ".metrics.json") == tmp_path / "sub" / "walk.odom.metrics.json"
