"""Field edits for the fuzz harness: each takes a ``Case`` (the decoded messages of one log and a seeded RNG),
edits copies of a few messages in place and returns a one-line description of what it did.

Hostile header stamps, record times and IMU gaps; IMU, wheel and ground-truth values out of range; per-point
times and coordinates; PointField and PointCloud2 layout; LaserScan geometry; frame ids; /tf_static cycles,
contradictions and non-unit quaternions; dropped, duplicated and reordered messages.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

S_NS = 1_000_000_000
_NP = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def kind(msgtype: str) -> str:
    return msgtype.rsplit("/", 1)[-1]


class Case:
    """The messages of one log being mutated; edited entries are deep copies, so the cache stays intact."""

    def __init__(self, conns: list, msgs: list, rng: np.random.Generator) -> None:
        self.conns, self.msgs, self.rng = list(conns), [list(m) for m in msgs], rng
        self.expect_check_fail = False  # set by mutations `info --check` must report

    def indices(self, *kinds: str) -> list[int]:
        return [i for i, m in enumerate(self.msgs) if kind(m[1]) in kinds]

    def has(self, *kinds: str) -> bool:
        return bool(self.indices(*kinds))

    def pick(self, *kinds: str, early: bool = False) -> int:
        idx = self.indices(*kinds)
        if early or self.rng.random() < 0.3:  # the first messages matter most (initialisation, first scan)
            idx = idx[:5]
        return idx[int(self.rng.integers(len(idx)))]

    def edit(self, i: int):
        """The message at ``i``, replaced by a private copy to edit."""
        self.msgs[i][3] = copy.deepcopy(self.msgs[i][3])
        return self.msgs[i][3]

    def choice(self, seq):
        return seq[int(self.rng.integers(len(seq)))]


def stamp_ns(msg) -> int:
    return int(msg.header.stamp.sec) * S_NS + int(msg.header.stamp.nanosec)


def set_stamp(msg, ns: int) -> None:
    ns = max(0, min(int(ns), (2**31 - 1) * S_NS))  # header sec is int32 in ROS 2
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns // S_NS, ns % S_NS


def cloud_array(msg) -> np.ndarray:
    order = ">" if msg.is_bigendian else "<"
    dt = np.dtype({"names": [f.name for f in msg.fields], "offsets": [f.offset for f in msg.fields],
                   "formats": [order + _NP[f.datatype] for f in msg.fields], "itemsize": msg.point_step})
    return np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dt).copy()


def set_cloud_array(msg, arr: np.ndarray) -> None:
    msg.data = np.frombuffer(arr.tobytes(), dtype=np.uint8).copy()


TIME_FIELDS = ("t", "offset_time", "time", "timestamp", "timestamps", "stamps")
SENSORS = ("PointCloud2", "LaserScan", "Imu", "Odometry", "TwistStamped")


# ---------------------------------------------------------------- stamps and record times

def m_stamp(c: Case) -> str:
    i = c.pick(*SENSORS, "PoseStamped")
    msg = c.edit(i)
    old = stamp_ns(msg)
    prev = [stamp_ns(m[3]) for m in c.msgs[:i] if m[0] == c.msgs[i][0]]
    what = c.choice(["0", "2^31 s", "+1e6 s", "+1e7 s", "duplicate", "backwards 30 ms"])
    new = {"0": 0, "2^31 s": (2**31 - 1) * S_NS, "+1e6 s": old + 10**6 * S_NS, "+1e7 s": old + 10**7 * S_NS,
           "duplicate": prev[-1] if prev else old, "backwards 30 ms": (prev[-1] if prev else old) - 30_000_000}[what]
    set_stamp(msg, new)
    # what `info --check` must report; a stamp 30 ms behind its predecessor is within the stream's 0.5 s reorder
    # window, which sorts it into place by design (a message recorded late), so only the far-off stamps count
    if kind(c.msgs[i][1]) in ("PointCloud2", "LaserScan", "Imu"):
        c.expect_check_fail = c.expect_check_fail or what not in ("duplicate", "backwards 30 ms")
    return f"{c.msgs[i][0]} message {i}: header stamp -> {what}"


def m_record_time(c: Case) -> str:
    i = int(c.rng.integers(len(c.msgs)))
    what = c.choice(["+1e6 s", "0", "-1 s"])
    t = c.msgs[i][2]
    c.msgs[i][2] = {"+1e6 s": t + 10**6 * S_NS, "0": 0, "-1 s": max(0, t - S_NS)}[what]
    return f"{c.msgs[i][0]} message {i}: record time -> {what}"


def m_imu_gap(c: Case) -> str:
    idx = c.indices("Imu")
    a = int(c.rng.integers(max(1, len(idx) // 2)))
    n = int(c.rng.integers(20, max(21, len(idx) // 2)))
    drop = set(idx[a:a + n])
    c.msgs = [m for j, m in enumerate(c.msgs) if j not in drop]
    return f"IMU: {n} samples dropped from sample {a}"


# ---------------------------------------------------------------- IMU and wheel values

def m_imu_value(c: Case) -> str:
    value = c.choice([1e300, -1e300, float("nan"), float("inf"), 1e30, 0.0])
    field = c.choice(["linear_acceleration", "angular_velocity"])
    if value == 0.0 and c.rng.random() < 0.5:
        for i in c.indices("Imu"):
            v = getattr(c.edit(i), field)
            v.x = v.y = v.z = 0.0
        return f"IMU: every {field} all-zero"
    i = c.pick("Imu")
    v = getattr(c.edit(i), field)
    setattr(v, c.choice("xyz"), value)
    c.expect_check_fail = c.expect_check_fail or not np.isfinite(value) or abs(value) > 1e20
    return f"IMU message {i}: {field} component -> {value!r}"


def m_odometry(c: Case) -> str:
    i = c.pick("Odometry")
    msg = c.edit(i)
    what = c.choice(["pose quaternion (0,0,0,0)", "twist NaN", "twist 1e300", "child_frame_id ''"])
    if what.startswith("pose"):
        q = msg.pose.pose.orientation
        q.x = q.y = q.z = q.w = 0.0
    elif what.startswith("twist"):
        msg.twist.twist.linear.x = float("nan") if "NaN" in what else 1e300
        c.expect_check_fail = True
    else:
        msg.child_frame_id = ""
    return f"wheel odometry message {i}: {what}"


def m_ground_truth(c: Case) -> str:
    i = c.pick("PoseStamped")
    msg = c.edit(i)
    if c.rng.random() < 0.5:
        q = msg.pose.orientation
        q.x = q.y = q.z = q.w = 0.0
        return f"ground truth message {i}: quaternion (0,0,0,0)"
    msg.pose.position.x = float("nan")
    return f"ground truth message {i}: position x NaN"


# ---------------------------------------------------------------- clouds: per-point values

def m_point_time(c: Case) -> str:
    i = c.pick("PointCloud2")
    msg = c.edit(i)
    arr = cloud_array(msg)
    name = next((n for n in TIME_FIELDS if n in arr.dtype.names), None)
    if name is None:
        return m_point_xyz(c)
    col, k = arr[name], int(c.rng.integers(len(arr)))
    if col.dtype.kind == "f":
        absolute = float(np.nanmax(col)) > 1e6
        what = c.choice(["5e5 s", "-5e5 s", "NaN", "inf", "1e30", "all 0", "all NaN", "reversed"])
        vals = {"5e5 s": 5e5 + (col[k] if absolute else 0), "-5e5 s": -5e5 + (col[k] if absolute else 0),
                "NaN": np.nan, "inf": np.inf, "1e30": 1e30}
    else:
        what = c.choice(["max", "all 0", "reversed"])
        vals = {"max": np.iinfo(col.dtype).max}
    if what in vals:
        col[k] = vals[what]
        c.expect_check_fail = c.expect_check_fail or what not in ("NaN", "inf")  # finite but absurd
    elif what == "all 0":
        col[:] = 0
    elif what == "all NaN":
        col[:] = np.nan
    else:
        col[:] = col[::-1].copy()
    set_cloud_array(msg, arr)
    return f"cloud message {i}: per-point '{name}' " + (f"of point {k} -> {what}" if what in vals else f"-> {what}")


def m_point_xyz(c: Case) -> str:
    i = c.pick("PointCloud2")
    msg = c.edit(i)
    arr = cloud_array(msg)
    what = c.choice(["one point 1e30", "one point inf", "all NaN", "all zero", "all one point"])
    k = int(c.rng.integers(len(arr)))
    if what.startswith("one"):
        arr["x"][k] = 1e30 if "1e30" in what else np.inf
    elif what == "all NaN":
        arr["x"][:] = np.nan
    elif what == "all zero":
        arr["x"][:] = arr["y"][:] = arr["z"][:] = 0
    else:
        for n in "xyz":
            arr[n][:] = arr[n][k]
    set_cloud_array(msg, arr)
    return f"cloud message {i}: xyz {what}"


# ---------------------------------------------------------------- clouds: layout

def m_pointfield(c: Case) -> str:
    i = c.pick("PointCloud2")
    msg = c.edit(i)
    names = [f.name for f in msg.fields]
    j = int(c.rng.integers(len(names)))
    f = msg.fields[j]
    what = c.choice(["count 2", "offset past point_step", "offset onto x", "datatype", "drop field",
                     "duplicate name", "rename"])
    if what == "count 2":
        j = names.index(c.choice(["x", "y", "z"] + [n for n in names if n in TIME_FIELDS]))
        msg.fields[j] = dataclasses.replace(msg.fields[j], count=2)
        f = msg.fields[j]
    elif what == "offset past point_step":
        msg.fields[j] = dataclasses.replace(f, offset=int(msg.point_step + c.rng.integers(0, 8)))
    elif what == "offset onto x":
        msg.fields[j] = dataclasses.replace(f, offset=msg.fields[0].offset)
    elif what == "datatype":
        dt = c.choice([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 255])
        msg.fields[j] = dataclasses.replace(f, datatype=dt)
        what = f"datatype {dt}"
    elif what == "drop field":
        del msg.fields[j]
    elif what == "duplicate name":
        msg.fields[j] = dataclasses.replace(f, name=msg.fields[(j + 1) % len(names)].name)
    else:
        msg.fields[j] = dataclasses.replace(f, name="zz_" + f.name)
    return f"cloud message {i}: PointField '{f.name}' {what}"


def m_cloud_layout(c: Case) -> str:
    i = c.pick("PointCloud2")
    msg = c.edit(i)
    what = c.choice(["point_step 0", "point_step -4", "point_step +4", "point_step 2^31", "width x2", "width 0",
                     "height 0", "height 2", "row_step 0", "big-endian flag flipped", "data cut by 3 bytes",
                     "data empty"])
    if what.startswith("point_step"):
        msg.point_step = {"0": 0, "-4": msg.point_step - 4, "+4": msg.point_step + 4, "2^31": 2**31}[what.split()[1]]
    elif what.startswith("width"):
        msg.width = msg.width * 2 if "x2" in what else 0
    elif what.startswith("height"):
        msg.height = int(what.split()[1])
    elif what == "row_step 0":
        msg.row_step = 0
    elif what.startswith("big"):
        msg.is_bigendian = not msg.is_bigendian
    else:
        data = np.asarray(msg.data, dtype=np.uint8)
        msg.data = data[:-3].copy() if "3 bytes" in what else data[:0].copy()
    return f"cloud message {i}: {what}"


def m_laserscan(c: Case) -> str:
    i = c.pick("LaserScan")
    msg = c.edit(i)
    nan = float("nan")
    what = c.choice(["angle_increment 0", "angle_increment NaN", "angle_increment negated", "angle_min NaN",
                     "ranges all NaN", "ranges all inf", "ranges negative", "range_min > range_max",
                     "time_increment 1e6", "time_increment -1", "scan_time 0", "scan_time NaN", "ranges empty"])
    key, _, val = what.partition(" ")
    if key == "ranges":
        r = np.asarray(msg.ranges, dtype=np.float32)
        msg.ranges = {"all NaN": np.full_like(r, nan), "all inf": np.full_like(r, np.inf), "negative": -r,
                      "empty": r[:0].copy()}[val]
    elif key == "range_min":
        msg.range_min, msg.range_max = msg.range_max + 1.0, msg.range_min
    elif val == "negated":
        msg.angle_increment = -msg.angle_increment
    else:
        setattr(msg, key, {"0": 0.0, "NaN": nan, "1e6": 1e6, "-1": -1.0}[val])
    return f"scan message {i}: {what}"


def m_frame_id(c: Case) -> str:
    i = c.pick("PointCloud2", "LaserScan", "Imu")
    msg = c.edit(i)
    new = c.choice(["", "nonexistent", "/" + msg.header.frame_id, "x" * 10000])
    msg.header.frame_id = new
    return f"{c.msgs[i][0]} message {i}: frame_id -> '{new[:20]}'" + ("..." if len(new) > 20 else "")


# ---------------------------------------------------------------- /tf_static

def m_tf_static(c: Case) -> str:
    i = c.indices("TFMessage")[0]
    msg = c.edit(i)
    trs = msg.transforms
    if not trs:
        return "/tf_static: left empty (nothing to edit)"
    tr = trs[int(c.rng.integers(len(trs)))]
    what = c.choice(["cycle", "contradiction", "duplicate child", "self loop", "quaternion x2", "quaternion x1.001",
                     "quaternion 0", "translation NaN", "empty", "second message"])
    if what in ("quaternion x2", "quaternion x1.001", "quaternion 0", "translation NaN"):
        q = tr.transform.rotation
        s = {"quaternion x2": 2.0, "quaternion x1.001": 1.001, "quaternion 0": 0.0}.get(what)
        if s is None:
            tr.transform.translation.x = float("nan")
        else:
            q.x, q.y, q.z, q.w = q.x * s, q.y * s, q.z * s, q.w * s
        return f"/tf_static {tr.header.frame_id}->{tr.child_frame_id}: {what}"
    if what == "empty":
        msg.transforms = []
        return "/tf_static: no transforms"
    new = copy.deepcopy(tr)
    parents = [t.header.frame_id for t in trs]
    children = [t.child_frame_id for t in trs]
    if what == "cycle":  # child -> parent again, with a different translation
        new.header.frame_id, new.child_frame_id = tr.child_frame_id, tr.header.frame_id
        new.transform.translation.x += 0.7
    elif what == "contradiction":  # a direct edge between two children that disagrees with the path via the parent
        others = [ch for ch in children if ch != tr.child_frame_id] or ["extra"]
        new.header.frame_id, new.child_frame_id = tr.child_frame_id, c.choice(others)
        new.transform.translation.y += 0.5
    elif what == "duplicate child":
        new.transform.translation.z += 1.0
    elif what == "self loop":
        new.child_frame_id = new.header.frame_id = c.choice(parents)
    else:  # a later /tf_static message redefining the same edge
        new.transform.translation.x -= 2.0
        extra = copy.deepcopy(msg)
        extra.transforms = [new]
        c.msgs.insert(len(c.msgs) // 2, [c.msgs[i][0], c.msgs[i][1], c.msgs[len(c.msgs) // 2][2], extra])
        return f"/tf_static: a second message redefines {tr.header.frame_id}->{tr.child_frame_id}"
    trs.append(new)
    return f"/tf_static: {what} ({new.header.frame_id}->{new.child_frame_id})"


# ---------------------------------------------------------------- GPS

def m_navsatfix(c: Case) -> str:
    what = c.choice(["latitude NaN", "longitude 1e300", "altitude -1e300", "latitude 91", "status -1 everywhere",
                     "covariance negative", "covariance NaN", "covariance 1e300", "covariance type 7",
                     "every fix the same stamp", "fixes reversed"])
    idx = c.indices("NavSatFix")
    if what in ("status -1 everywhere", "every fix the same stamp", "fixes reversed"):
        stamps = [stamp_ns(c.msgs[i][3]) for i in idx]
        for k, i in enumerate(idx):
            msg = c.edit(i)
            if what.startswith("status"):
                msg.status.status = -1
            else:
                set_stamp(msg, stamps[0] if what.startswith("every") else stamps[-1 - k])
        return f"GPS: {what}"
    i = c.pick("NavSatFix")
    msg = c.edit(i)
    key, _, val = what.partition(" ")
    v = {"NaN": float("nan"), "1e300": 1e300, "-1e300": -1e300, "91": 91.0, "negative": -4.0, "type 7": 7}[val]
    if key == "covariance":
        if val == "type 7":
            msg.position_covariance_type = 7
        else:
            cov = np.asarray(msg.position_covariance, dtype=np.float64).copy()
            cov[[0, 4, 8]] = v
            msg.position_covariance = cov
    else:
        setattr(msg, key, v)
    return f"GPS message {i}: {what}"


# ---------------------------------------------------------------- structure

def m_structure(c: Case) -> str:
    topics = [t for t, _, _ in c.conns]
    what = c.choice(["drop topic", "duplicate message", "swap record times"])
    if what == "drop topic":
        t = c.choice(topics)
        c.msgs = [m for m in c.msgs if m[0] != t]
        return f"all {t} messages dropped"
    i = int(c.rng.integers(1, len(c.msgs)))
    if what == "duplicate message":
        c.msgs.insert(i, list(c.msgs[i]))
        return f"{c.msgs[i][0]} message {i} written twice"
    c.msgs[i - 1][2], c.msgs[i][2] = c.msgs[i][2], c.msgs[i - 1][2]
    return f"record times of messages {i - 1} and {i} swapped"


FIELD_MUTATIONS = {  # name -> (function, message kinds it needs)
    "stamp": (m_stamp, ("PointCloud2", "LaserScan", "Imu")),
    "record_time": (m_record_time, ()),
    "imu_gap": (m_imu_gap, ("Imu",)),
    "imu_value": (m_imu_value, ("Imu",)),
    "odometry": (m_odometry, ("Odometry",)),
    "ground_truth": (m_ground_truth, ("PoseStamped",)),
    "point_time": (m_point_time, ("PointCloud2",)),
    "point_xyz": (m_point_xyz, ("PointCloud2",)),
    "pointfield": (m_pointfield, ("PointCloud2",)),
    "cloud_layout": (m_cloud_layout, ("PointCloud2",)),
    "laserscan": (m_laserscan, ("LaserScan",)),
    "frame_id": (m_frame_id, ("Imu",)),
    "tf_static": (m_tf_static, ("TFMessage",)),
    "navsatfix": (m_navsatfix, ("NavSatFix",)),
    "structure": (m_structure, ()),
}


def applicable(c: Case) -> list[str]:
    return [n for n, (_, need) in FIELD_MUTATIONS.items() if not need or any(c.has(k) for k in need)]
