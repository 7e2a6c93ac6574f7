"""``lio deskew`` from every input format to every output format (issue 12).

Inputs: a simulated ROS 1 bag and ROS 2 bag (sqlite3), the ROS 2 bag copied as stored into a ROS 2 bag of
mcap storage and a bare MCAP file, and the ROS 1 bag as an MCAP file of mcap's ros1 profile with a driver's
own message type beside it (/packets). Outputs: ROS 1 bag, ROS 2 bag (sqlite3, mcap), bare MCAP. Each run
de-skews with the ground-truth trajectory, so its points are checked against the true motion; every output
must be read by rosbags' AnyReader and pass ``lio info --check``; the other topics come out byte for byte
where the encoding stays, field for field where it is converted, and metrics.json counts which.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.io.logs.reader import open_log
from lio_cli.simulation.run import simulate

from .test_job import GT_MAX_M, GT_MEDIAN_M, SUFFIX, check_cloud_rules, deskew, errors, gt, stored_except

INPUTS = ("ros1", "ros2", "ros2-mcap", "mcap", "ros1-mcap")
OUTPUTS = ("ros1", "ros2", "ros2-mcap", "mcap")
ENCODING = {"ros1": "ros1", "ros1-mcap": "ros1", "ros2": "cdr", "ros2-mcap": "cdr", "mcap": "cdr"}  # of the
# messages in a log of each format; an MCAP output is always CDR (ros2 profile), which AnyReader reads
LIDAR = "/points"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, log_tools) -> dict:
    """Input format -> the simulated run with ``log_path`` that log (1.2 s: 12 scans of 32 columns)."""
    root = tmp_path_factory.mktemp("formats")
    opts = dict(duration_s=1.2, seed=3, columns=32, start="moving")
    bag = simulate("handheld", root / "walk.bag", "ros1", **opts)
    ros2 = simulate("handheld", root / "walk_ros2", "ros2", **opts)

    def run(sim, path):
        return SimpleNamespace(log_path=path, gt_path=sim.gt_path, truth_path=sim.truth_path)

    made = {"ros1": run(bag, bag.log_path), "ros2": run(ros2, ros2.log_path),
            "ros1-mcap": run(bag, log_tools.ros1_mcap(bag.log_path, root / "walk_ros1.mcap", packets=5))}
    for fmt, name in (("ros2-mcap", "walk_ros2_mcap"), ("mcap", "walk.mcap")):
        copy = log_tools.copy_log(ros2.log_path, root / name, fmt)
        assert copy.converted == {}  # both CDR: the same bytes in another container
        made[fmt] = run(ros2, root / name)
    return made


@pytest.mark.parametrize("dst", OUTPUTS)
@pytest.mark.parametrize("src", INPUTS)
def test_every_input_format_to_every_output_format(inputs, tmp_path, log_tools, src, dst):
    s = inputs[src]
    out = tmp_path / f"out{SUFFIX[dst] or '_bag'}"
    res = deskew(s.log_path, out, output_format=dst, **gt(s))
    assert res.format == dst
    with open_log(s.log_path) as r:
        counts = {topic: info.count for topic, info in r.topics.items()}

    # the de-skewed clouds: the standing sensor's scan, by the cloud rules
    err, _ = errors(s, out)
    assert np.median(err) < GT_MEDIAN_M and err.max() < GT_MAX_M
    check_cloud_rules(s.log_path, out)
    assert res.metrics["scans"] == {"total": 12, "deskewed": 12, "unchanged": 0, "unchanged_why": {}}

    # readable by rosbags and by lio's own check
    assert log_tools.anyreader_count(out) == sum(counts.values())
    assert main(["info", str(out), "--check", "-q"]) == 0

    # everything else: bytes where the encoding stays, fields where it is converted; counted so
    others = {topic: n for topic, n in counts.items() if topic != LIDAR}
    copied = res.metrics["copied_topics"]
    if ENCODING[src] == ENCODING[dst]:
        assert copied == {"as_stored": others, "converted": {}}
        assert stored_except(out, LIDAR) == stored_except(s.log_path, LIDAR)
    else:  # ROS 1 <-> CDR (a ROS 1 encoded MCAP written as MCAP too)
        assert copied == {"as_stored": {}, "converted": others}
        for topic in others:
            assert log_tools.decoded(out, topic) == log_tools.decoded(s.log_path, topic), topic
    if src == "ros1-mcap":
        assert others["/packets"] == 5  # a driver's own type, defined only by the schema the file stores
