"""Where a batch deskew run writes its log: a file with its format's suffix, a folder for a ROS 2 bag."""

from lio_cli.batch.commands import _deskew_out
from lio_cli.config.deskew import DeskewConfig


def test_a_folder_of_split_bags_gives_a_bag_file(tmp_path):
    split = tmp_path / "split"
    split.mkdir()
    (split / "a_0.bag").write_bytes(b"#ROSBAG V2.0\n")  # detected by its magic
    assert _deskew_out(tmp_path, split, DeskewConfig()).name == "deskewed.bag"


def test_the_asked_format_names_the_output(tmp_path):
    log = tmp_path / "walk.bag"
    log.write_bytes(b"#ROSBAG V2.0\n")
    assert _deskew_out(tmp_path, log, DeskewConfig()).name == "deskewed.bag"
    assert _deskew_out(tmp_path, log, DeskewConfig(output_format="mcap")).name == "deskewed.mcap"
    assert _deskew_out(tmp_path, log, DeskewConfig(output_format="ros2")).name == "deskewed"
