"""Trajectory sources: TUM and KITTI files, KITTI times, log topics and TF chains."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.io.sensors.sources import load_trajectory, split_source
from lio_cli.io.files.trajectory import format_kitti, format_stamp, format_tum, parse_stamp_ns, read_kitti, read_times, read_tum
from lio_cli.io.logs.writer import LogWriter

EXACT = 1e-12
WRITTEN = 1e-8  # files carry 9 decimals
S_ = 1_000_000_000  # one second in ns


def _poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3) * 10) for _ in range(n)])


def test_tum_round_trip_keeps_ns_stamps_exact(tmp_path: Path):
    stamps = np.array([1_700_000_000_123_456_789, 1_700_000_000_223_456_790], dtype=np.int64)
    poses = _poses(2)
    p = tmp_path / "t.tum"
    p.write_text("# comment\n" + format_tum(stamps, poses))
    s, P = read_tum(p)
    np.testing.assert_array_equal(s, stamps)
    np.testing.assert_allclose(P, poses, atol=WRITTEN)


def test_plain_and_commented_files_read_the_same(tmp_path: Path):
    """Plain tables take a vectorised path, anything else the line-by-line one: same result either way."""
    stamps = np.array([5, 1_000_000_001, 2_500_000_000], dtype=np.int64)
    text = format_tum(stamps, _poses(3, seed=4))
    plain, commented = tmp_path / "plain.tum", tmp_path / "commented.tum"
    plain.write_text(text)
    commented.write_text("# stamp x y z qx qy qz qw\n" + text.replace("\n", "\n\n", 1))
    (s1, p1), (s2, p2) = read_tum(plain), read_tum(commented)
    np.testing.assert_array_equal(s1, stamps)
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_array_equal(p1, p2)
    first, rest = text.split("\n", 1)
    commented.write_text("# header\n" + " ".join([first.split()[0], "nan", *first.split()[2:]]) + "\n" + rest)
    with pytest.raises(InputError, match=r"commented.tum:2: NaN or infinite value"):
        read_tum(commented)


def test_tum_stamp_units(tmp_path: Path):
    p = tmp_path / "t.tum"
    p.write_text("1700000000123456789 0 0 0 0 0 0 1\n1700000000223456789 1 0 0 0 0 0 1\n")
    s, _ = read_tum(p, stamp_unit="ns")
    np.testing.assert_array_equal(s, [1_700_000_000_123_456_789, 1_700_000_000_223_456_789])
    # odom --gt, deskew --trajectory and fuse --odom read it too: the message names evaluate's options as evaluate's
    with pytest.raises(InputError, match=r"t.tum:1: stamp 1700000000123456789 is too large for seconds .*TUM stamps are "
                                         r"seconds: write them so \(lio evaluate also reads other units with "
                                         r"--gt-stamp-unit/--est-stamp-unit\)$"):
        read_tum(p)
    # ns stamps read as us or ms: the unit asked for is named (it said "too large for seconds")
    for unit, finer in (("us", "ns"), ("ms", "us or ns")):
        with pytest.raises(InputError) as err:
            read_tum(p, stamp_unit=unit)
        assert str(err.value) == (f"{p}:1: stamp 1700000000123456789 is too large for {unit} (beyond year 2262); the "
                                  f"file's stamps look like {finer}: give that unit (--gt-stamp-unit/--est-stamp-unit)")
    p.write_text("17000000001234567890000 0 0 0 0 0 0 1\n")  # no unit makes this a time (it read "look like :")
    with pytest.raises(InputError) as err:
        read_tum(p, stamp_unit="ns")
    assert str(err.value) == (f"{p}:1: stamp 17000000001234567890000 is beyond what int64 nanoseconds hold (year "
                              "2262); it is no time stamp in any unit")
    p.write_text("1500 0 0 0 0 0 0 1\n2500.5 1 0 0 0 0 0 1\n")
    np.testing.assert_array_equal(read_tum(p, stamp_unit="ms")[0], [1_500_000_000, 2_500_500_000])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n", "t.tum:2: expected 8 values (stamp tx ty tz qx qy qz qw), found 7"),
        ("0 0 0 0 0 0 0 1\n1 0 x 0 0 0 0 1\n", "t.tum:2: 'x' is not a number"),
        ("0 0 0 0 0 0 0 1\n1 0 nan 0 0 0 0 1\n", "t.tum:2: NaN or infinite value"),
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 2\n", "t.tum:2: quaternion is not unit length (norm 2.000000)"),
        ("0 0 0 0 0 0 0 1\n\n2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", "t.tum:4: timestamp 1 goes backwards from the previous line's (2); stamps must increase strictly"),
        ("0 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", "t.tum:2: timestamp 0 repeats the previous line's (0); stamps must increase strictly"),
        ("abc 0 0 0 0 0 0 1\n", "t.tum:1: stamp 'abc' is not a number"),
        ("# only a comment\n", "t.tum: no poses in file"),
    ],
)
def test_tum_bad_lines_name_the_line(tmp_path: Path, text: str, message: str):
    p = tmp_path / "t.tum"
    p.write_text(text)
    with pytest.raises(InputError) as err:
        read_tum(p)
    assert str(err.value) == f"{tmp_path}/{message}"


def test_a_quaternion_of_1e300_is_refused_without_a_warning(tmp_path: Path):
    # fuzz, issue 32: numpy's overflow warning came before the one error line
    import warnings

    p = tmp_path / "t.tum"
    p.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 1e300 0 0 1\n")
    with warnings.catch_warnings(), pytest.raises(InputError) as err:
        warnings.simplefilter("error")
        read_tum(p)
    assert str(err.value) == f"{p}:2: quaternion is not unit length (norm inf)"


def test_kitti_poses_and_times(tmp_path: Path):
    poses = _poses(3, seed=2)
    p = tmp_path / "poses.txt"
    p.write_text(format_kitti(poses))
    np.testing.assert_allclose(read_kitti(p), poses, atol=WRITTEN)
    t = tmp_path / "times.txt"
    t.write_text("0.000000e+00\n1.036000e-01\n2.072000e-01\n")
    np.testing.assert_array_equal(read_times(t), [0, 103_600_000, 207_200_000])
    loaded = load_trajectory(str(p), times=t)
    assert loaded.kind == "kitti" and len(loaded) == 3
    np.testing.assert_array_equal(load_trajectory(str(p), rate_hz=10.0).stamps_ns, [0, 100_000_000, 200_000_000])


def test_kitti_bad_inputs(tmp_path: Path):
    p = tmp_path / "poses.txt"
    p.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(InputError, match=r"poses.txt:2: expected 12 values \(KITTI row-major 3x4 pose\), found 11"):
        read_kitti(p)
    p.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n2 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(InputError, match=r"poses.txt:2: the 3x3 block is not a rotation"):
        read_kitti(p)
    p.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n")
    t = tmp_path / "times.txt"
    t.write_text("0.0\n")
    with pytest.raises(InputError, match=r"2 KITTI poses but .*times.txt holds 1 stamps"):
        load_trajectory(str(p), times=t)
    with pytest.raises(InputError, match=r"KITTI poses carry no stamps; give --times FILE \(KITTI times.txt\) or --rate HZ"):
        load_trajectory(str(p), stamp_options=True)
    # odom --gt, fuse --odom and deskew --trajectory have no --times/--rate: the line named options they lack
    with pytest.raises(InputError) as err:
        load_trajectory(str(p))
    assert str(err.value) == (f"{p}: KITTI poses carry no stamps; give a TUM file (stamp tx ty tz qx qy qz qw per "
                              "line, as lio odom writes)")


def test_split_source_forms(tmp_path: Path):
    assert split_source("run.bag:/gt") == ("run.bag", "/gt")
    assert split_source("run.bag#/gt") == ("run.bag", "/gt")
    assert split_source("run.bag#gt") == ("run.bag", "gt")
    assert split_source("run.bag:tf:map.base") == ("run.bag", "tf:map.base")
    assert split_source("est.tum") == ("est.tum", None)
    odd = tmp_path / "gt#1.tum"  # an existing file wins over the topic syntax
    odd.write_text("0 0 0 0 0 0 0 1\n")
    assert split_source(str(odd)) == (str(odd), None)


def _write_gt_bag(path: Path, fmt: str = "ros1") -> tuple[np.ndarray, np.ndarray]:
    stamps = (np.arange(20) * 100_000_000 + 5_000_000_000).astype(np.int64)
    poses = np.stack([make_pose(so3_exp(np.array([0.0, 0.0, 0.1 * k])), [0.5 * k, 0.1 * k, 0.0]) for k in range(20)])
    with LogWriter(path, fmt) as w:
        w.add_topic("/ground_truth", "geometry_msgs/msg/PoseStamped")
        w.add_topic("/odom", "nav_msgs/msg/Odometry")
        for s, T in zip(stamps, poses):
            w.write("/ground_truth", int(s), w.make.pose_stamped(int(s), "world", T))
            w.write("/odom", int(s), w.make.odometry(int(s), "odom", "base", T, [0, 0, 0], [0, 0, 0]))
    return stamps, poses


@pytest.mark.parametrize("fmt", ["ros1", "mcap"])
def test_log_topic_sources(tmp_path: Path, fmt: str):
    bag = tmp_path / ("run.bag" if fmt == "ros1" else "run.mcap")
    stamps, poses = _write_gt_bag(bag, fmt)
    for spec in (f"{bag}:/ground_truth", f"{bag}#/ground_truth"):
        t = load_trajectory(spec)
        np.testing.assert_array_equal(t.stamps_ns, stamps)
        np.testing.assert_allclose(t.poses, poses, atol=EXACT)
    t = load_trajectory(str(bag))  # bare log: the only PoseStamped topic
    assert t.name.endswith(":/ground_truth")
    np.testing.assert_allclose(load_trajectory(f"{bag}:/odom").poses, poses, atol=EXACT)
    with pytest.raises(InputError, match=r"topic /nope not found; ground-truth topics here: /ground_truth, /odom"):
        load_trajectory(f"{bag}:/nope")


def test_tf_chain_source(tmp_path: Path):
    bag = tmp_path / "tf.bag"
    T_map_world = make_pose(so3_exp(np.array([0.0, 0.0, 0.5])), [10.0, 0.0, 1.0])
    T_base_lidar = make_pose(t=[0.2, 0.0, 0.3])
    stamps = (np.arange(10) * 50_000_000 + 1_000_000_000).astype(np.int64)
    T_world_base = [make_pose(so3_exp(np.array([0.0, 0.05 * k, 0.0])), [float(k), 0.0, 0.0]) for k in range(10)]
    with LogWriter(bag, "ros1") as w:
        w.add_topic("/tf_static", "tf2_msgs/msg/TFMessage", latching=True)
        w.add_topic("/tf", "tf2_msgs/msg/TFMessage")
        w.write("/tf_static", int(stamps[0]), w.make.tf_message([
            w.make.transform_stamped(int(stamps[0]), "map", "world", T_map_world),
            w.make.transform_stamped(int(stamps[0]), "base", "lidar", T_base_lidar)]))
        for s, T in zip(stamps, T_world_base):
            w.write("/tf", int(s), w.make.tf_message([w.make.transform_stamped(int(s), "world", "base", T)]))
    t = load_trajectory(f"{bag}:tf:map.lidar")
    np.testing.assert_array_equal(t.stamps_ns, stamps)
    expected = np.stack([T_map_world @ T @ T_base_lidar for T in T_world_base])
    np.testing.assert_allclose(t.poses, expected, atol=1e-9)
    inverse = load_trajectory(f"{bag}:tf:lidar->map")
    np.testing.assert_allclose(inverse.poses @ expected, np.repeat(np.eye(4)[None], 10, axis=0), atol=1e-9)
    with pytest.raises(InputError, match=r"frames of tf:map.odom not found .* \(frames there: base, lidar, map, world\)"):
        load_trajectory(f"{bag}:tf:map.odom")
    with pytest.raises(InputError, match=r"'base' -> 'lidar' is static"):
        load_trajectory(f"{bag}:tf:base.lidar")


def test_stamp_helpers_unchanged():
    assert format_stamp(1_500_000_001) == "1.500000001"
    assert parse_stamp_ns("1.500000001") == 1_500_000_001


def test_tf_chain_interpolates_the_slower_dynamic_edge(tmp_path: Path):
    """map -> odom at 2 Hz drifting linearly in x, odom -> base at 20 Hz: output at the 20 Hz stamps."""
    bag = tmp_path / "tf2.bag"
    slow = (np.arange(3) * 500_000_000 + S_).astype(np.int64)  # 1.0, 1.5, 2.0 s
    fast = (np.arange(21) * 50_000_000 + S_).astype(np.int64)  # 1.0 .. 2.0 s
    with LogWriter(bag, "ros1") as w:
        w.add_topic("/tf", "tf2_msgs/msg/TFMessage")
        for s in np.union1d(slow, fast):
            msgs = []
            if s in slow:
                msgs.append(w.make.transform_stamped(int(s), "map", "odom", make_pose(t=[(s - S_) / 1e9, 0, 0])))
            if s in fast:
                msgs.append(w.make.transform_stamped(int(s), "odom", "base", make_pose(t=[0, (s - S_) / 1e9, 0])))
            w.write("/tf", int(s), w.make.tf_message(msgs))
    t = load_trajectory(f"{bag}#tf:map.base")
    np.testing.assert_array_equal(t.stamps_ns, fast)
    elapsed = (fast - S_) / 1e9
    np.testing.assert_allclose(t.poses[:, :3, 3], np.stack([elapsed, elapsed, 0 * elapsed], axis=1), atol=1e-9)



@pytest.mark.parametrize("kind", ["tum", "kitti"])
def test_a_trajectory_from_a_pipe_is_read_once_and_whole(tmp_path, kind):
    # `lio evaluate <(zcat gt.tum.gz) est.tum`: the format is sniffed from the same text that is parsed, a
    # pipe giving its bytes only once
    import os
    import threading

    poses = np.repeat(np.eye(4)[None], 50, axis=0)
    poses[:, 0, 3] = np.arange(50) * 0.1
    text = format_tum(np.arange(50) * 10**8, poses) if kind == "tum" else format_kitti(poses)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: fifo.write_text(text), daemon=True)
    writer.start()
    got = []  # read in a thread: a reader that opens the pipe twice would wait forever for a second writer
    reader = threading.Thread(target=lambda: got.append(load_trajectory(str(fifo), rate_hz=10.0 if kind == "kitti" else None)),
                              daemon=True)
    reader.start()
    reader.join(timeout=20)
    assert got, "the pipe was not read in one go"
    traj = got[0]
    assert len(traj) == 50
    np.testing.assert_allclose(traj.poses[:, 0, 3], poses[:, 0, 3], atol=1e-9)
    np.testing.assert_array_equal(traj.stamps_ns, np.arange(50) * 10**8)
