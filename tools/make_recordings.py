#!/usr/bin/env python3
"""Write one drive in every recording format `humem eval --source` reads.

From a HuMem `loop` folder (sequence/*.jpg and sequence_poses.txt, TUM
poses), takes every N-th frame and writes, under OUT:

  folder/       the same frames as a HuMem folder (the reference)
  ros2/         a ROS 2 bag in MCAP: sensor_msgs/msg/Image (rgb8, the
                decoded pixels) on /camera/image_raw, nav_msgs/msg/Odometry
                on /odom, and geometry_msgs/msg/PoseStamped on /pose
  drive.bag     a ROS 1 bag (LZ4 chunks): sensor_msgs/CompressedImage (the
                JPEG bytes) on /camera/image/compressed, and tf2_msgs/TFMessage
                map -> camera on /tf
  tum/          TUM RGB-D: rgb.txt, rgb/*.jpg, groundtruth.txt
  euroc/        EuRoC/ASL: mav0/cam0/data.csv, mav0/cam0/data/*.png,
                mav0/state_groundtruth_estimate0/data.csv
  kitti/        KITTI odometry: sequences/00/image_2/*.png, times.txt,
                poses/00.txt
  robot/        a ROS 2 bag in MCAP laid out as a robot records one:
                JPEG sensor_msgs/msg/CompressedImage in the frame
                camera_optical with its sensor_msgs/msg/CameraInfo, the
                body's nav_msgs/msg/Odometry (odom -> base_link) at 20 Hz at
                other times than the images, and the TF tree map -> odom
                (1 Hz) -> base_link (20 Hz) on /tf, base_link ->
                camera_optical (the camera's mounting) on /tf_static
  robot_db3/    the same drive in SQLite storage (ROS 2 Humble's default),
                split into two .db3 files listed by its metadata.yaml

The bags are written with `rosbags`, a ROS-free implementation of both bag
formats that owes nothing to HuMem's readers, so a test comparing
`humem eval` on each against the folder checks the readers against an
independent writer. Every format carries the same pixels (the PNGs and raw
images are the JPEGs decoded by Pillow, as HuMem's decoder decodes them)
and the same poses at the images' own times, except the robot layouts: they
carry the camera's pose only through the body's odometry and the TF tree,
at their own times, so a reader must compose and interpolate to recover it.

Usage: make_recordings.py LOOP_FOLDER OUT [--every N] [--limit M]
"""

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import yaml
from PIL import Image
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

# ROS times start here, so that no stamp is zero (a zero stamp means
# "not set" to HuMem's readers, which then take the bag's log time).
EPOCH_NS = 1_700_000_000 * 10**9


def read_loop(folder: Path, every: int, limit: int | None):
    images = sorted((folder / "sequence").glob("*.jpg"))
    poses = []
    for line in (folder / "sequence_poses.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            poses.append([float(v) for v in line.split()])
    assert len(images) == len(poses), f"{len(images)} images, {len(poses)} poses"
    frames = []
    for i in range(0, len(images), every):
        t, x, y, z, qx, qy, qz, qw = poses[i]
        stamp_ns = EPOCH_NS + round(t * 1e9)
        frames.append((stamp_ns, images[i], (x, y, z), (qx, qy, qz, qw)))
    return frames[:limit] if limit else frames


def read_truth(folder: Path):
    """Every frame's camera pose (10 Hz): times (ns) and 4x4 matrices."""
    times, poses = [], []
    for line in (folder / "sequence_poses.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            t, x, y, z, qx, qy, qz, qw = (float(v) for v in line.split())
            times.append(EPOCH_NS + round(t * 1e9))
            poses.append(matrix((x, y, z), (qx, qy, qz, qw)))
    return np.array(times), poses


def matrix(t, q):
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = t
    return m


def quaternion(m):
    """(x, y, z, w) of a rotation matrix (Shepperd's method)."""
    r = m[:3, :3]
    tr = np.trace(r)
    if tr > 0:
        s = 2 * np.sqrt(1 + tr)
        q = ((r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4)
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + r[i, i] - r[j, j] - r[k, k])
        v = [0.0, 0.0, 0.0]
        v[i] = s / 4
        v[j] = (r[j, i] + r[i, j]) / s
        v[k] = (r[k, i] + r[i, k]) / s
        q = (*v, (r[k, j] - r[j, k]) / s)
    q = np.array(q)
    return q if q[3] >= 0 else -q


def slerp(q0, q1, s):
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    a = np.arccos(d)
    return (np.sin((1 - s) * a) * q0 + np.sin(s * a) * q1) / np.sin(a)


def truth_at(times, poses, ns):
    """The camera's pose at `ns`: interpolated between the frames either
    side, extrapolated from the first or last two frames (a car does not
    stand still before its first frame)."""
    i = min(max(int(np.searchsorted(times, ns)), 1), len(times) - 1)
    s = (ns - times[i - 1]) / (times[i] - times[i - 1])
    a, b = poses[i - 1], poses[i]
    return matrix(a[:3, 3] + s * (b[:3, 3] - a[:3, 3]), slerp(quaternion(a), quaternion(b), s))


def write_folder(out: Path, frames):
    (out / "sequence").mkdir(parents=True)
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for k, (ns, jpg, t, q) in enumerate(frames):
        shutil.copyfile(jpg, out / "sequence" / f"{k:06d}.jpg")
        lines.append(f"{ns * 1e-9:.9f} {t[0]} {t[1]} {t[2]} {q[0]} {q[1]} {q[2]} {q[3]}")
    (out / "sequence_poses.txt").write_text("\n".join(lines) + "\n")


def pixels(jpg: Path) -> np.ndarray:
    return np.asarray(Image.open(jpg).convert("RGB"))


def write_ros2(out: Path, frames):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]
    Pose = T["geometry_msgs/msg/Pose"]
    Point = T["geometry_msgs/msg/Point"]
    Quat = T["geometry_msgs/msg/Quaternion"]

    def header(ns, frame):
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame)

    def pose(t, q):
        return Pose(position=Point(x=t[0], y=t[1], z=t[2]), orientation=Quat(x=q[0], y=q[1], z=q[2], w=q[3]))

    with Ros2Writer(out, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        image_c = w.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        odom_c = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        pose_c = w.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for ns, jpg, t, q in frames:
            px = pixels(jpg)
            h, wd, _ = px.shape
            img = T["sensor_msgs/msg/Image"](
                header=header(ns, "camera"), height=h, width=wd, encoding="rgb8",
                is_bigendian=0, step=wd * 3, data=px.reshape(-1).astype(np.uint8))
            w.write(image_c, ns, ts.serialize_cdr(img, "sensor_msgs/msg/Image"))
            cov = np.zeros(36, dtype=np.float64)
            odom = T["nav_msgs/msg/Odometry"](
                header=header(ns, "map"), child_frame_id="camera",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(t, q), covariance=cov),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](
                        linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                    covariance=cov))
            w.write(odom_c, ns, ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
            stamped = T["geometry_msgs/msg/PoseStamped"](header=header(ns, "map"), pose=pose(t, q))
            w.write(pose_c, ns, ts.serialize_cdr(stamped, "geometry_msgs/msg/PoseStamped"))


def write_ros1(out: Path, frames):
    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]
    # ROS 1 Noetic's store has no tf2_msgs; its definition is one line.
    ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    w = Ros1Writer(out)
    w.set_compression(Ros1Writer.CompressionFormat.LZ4)
    with w:
        image_c = w.add_connection("/camera/image/compressed", "sensor_msgs/msg/CompressedImage", typestore=ts)
        tf_c = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        for seq, (ns, jpg, t, q) in enumerate(frames):
            stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
            img = T["sensor_msgs/msg/CompressedImage"](
                header=Header(seq=seq, stamp=stamp, frame_id="camera"), format="jpeg",
                data=np.frombuffer(jpg.read_bytes(), dtype=np.uint8))
            w.write(image_c, ns, ts.serialize_ros1(img, "sensor_msgs/msg/CompressedImage"))
            transform = T["geometry_msgs/msg/TransformStamped"](
                header=Header(seq=seq, stamp=stamp, frame_id="map"), child_frame_id="camera",
                transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
                    rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))
            tf = T["tf2_msgs/msg/TFMessage"](transforms=[transform])
            w.write(tf_c, ns, ts.serialize_ros1(tf, "tf2_msgs/msg/TFMessage"))


def write_png(jpg: Path, png: Path):
    Image.fromarray(pixels(jpg)).save(png)


def write_tum(out: Path, frames):
    (out / "rgb").mkdir(parents=True)
    rgb = ["# color images", "# timestamp filename"]
    truth = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for ns, jpg, t, q in frames:
        stamp = f"{ns // 10**9}.{ns % 10**9:09d}"
        shutil.copyfile(jpg, out / "rgb" / f"{stamp}.jpg")
        rgb.append(f"{stamp} rgb/{stamp}.jpg")
        truth.append(f"{stamp} {t[0]} {t[1]} {t[2]} {q[0]} {q[1]} {q[2]} {q[3]}")
    (out / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (out / "groundtruth.txt").write_text("\n".join(truth) + "\n")


def write_euroc(out: Path, frames):
    cam = out / "mav0" / "cam0"
    (cam / "data").mkdir(parents=True)
    gt = out / "mav0" / "state_groundtruth_estimate0"
    gt.mkdir(parents=True)
    cam_csv = ["#timestamp [ns],filename"]
    gt_csv = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"]
    for ns, jpg, t, q in frames:
        write_png(jpg, cam / "data" / f"{ns}.png")
        cam_csv.append(f"{ns},{ns}.png")
        gt_csv.append(f"{ns},{t[0]},{t[1]},{t[2]},{q[3]},{q[0]},{q[1]},{q[2]}")
    (cam / "data.csv").write_text("\n".join(cam_csv) + "\n")
    (gt / "data.csv").write_text("\n".join(gt_csv) + "\n")


def write_kitti(out: Path, frames):
    seq = out / "sequences" / "00"
    (seq / "image_2").mkdir(parents=True)
    (out / "poses").mkdir(parents=True)
    times, poses = [], []
    t0 = frames[0][0]
    for k, (ns, jpg, t, q) in enumerate(frames):
        write_png(jpg, seq / "image_2" / f"{k:06d}.png")
        times.append(f"{(ns - t0) * 1e-9:.6e}")
        x, y, z, w = q
        r = [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
        poses.append(" ".join(f"{v:.9e}" for row, ti in zip(r, t) for v in (*row, ti)))
    (seq / "times.txt").write_text("\n".join(times) + "\n")
    (out / "poses" / "00.txt").write_text("\n".join(poses) + "\n")


# The camera's mounting on the body: 0.4 m ahead of base_link and 1.2 m up,
# as an optical frame (x right, y down, z forward) on a body that looks
# along x with z up.
BASE_TO_CAMERA = np.array([
    [0.0, 0.0, 1.0, 0.4],
    [-1.0, 0.0, 0.0, 0.0],
    [0.0, -1.0, 0.0, 1.2],
    [0.0, 0.0, 0.0, 1.0],
])
# Where odometry started in the map: 12 m east, 7 m south, turned 25°.
_yaw = np.radians(25.0)
MAP_TO_ODOM = np.array([
    [np.cos(_yaw), -np.sin(_yaw), 0.0, 12.0],
    [np.sin(_yaw), np.cos(_yaw), 0.0, -7.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
])


def robot_messages(loop: Path, frames):
    """The robot layout's messages, (ns, topic, type, message), in time order."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]
    V3 = T["geometry_msgs/msg/Vector3"]
    Quat = T["geometry_msgs/msg/Quaternion"]

    def header(ns, frame):
        return Header(stamp=Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9)), frame_id=frame)

    def transform(ns, parent, child, m):
        q = quaternion(m)
        return T["geometry_msgs/msg/TransformStamped"](
            header=header(ns, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=V3(x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                rotation=Quat(x=q[0], y=q[1], z=q[2], w=q[3])))

    times, poses = read_truth(loop)
    calib = json.loads((loop / "sequence_calib.json").read_text())
    camera_to_base = np.linalg.inv(BASE_TO_CAMERA)
    odom_from_map = np.linalg.inv(MAP_TO_ODOM)
    first, last = frames[0][0], frames[-1][0]
    out = []
    # The mounting, once, before anything else.
    out.append((first - 10**9, "/tf_static", "tf2_msgs/msg/TFMessage", T["tf2_msgs/msg/TFMessage"](
        transforms=[transform(first - 10**9, "base_link", "camera_optical", BASE_TO_CAMERA)])))
    # Localisation: map -> odom at 1 Hz, from before the first image to after the last.
    for ns in range(first - 10**9, last + 2 * 10**9, 10**9):
        out.append((ns, "/tf", "tf2_msgs/msg/TFMessage", T["tf2_msgs/msg/TFMessage"](
            transforms=[transform(ns, "map", "odom", MAP_TO_ODOM)])))
    # Odometry at 20 Hz, 13 ms off the camera's clock.
    cov = np.zeros(36, dtype=np.float64)
    zero = V3(x=0.0, y=0.0, z=0.0)
    for ns in range(first - 10**9 + 13 * 10**6, last + 10**9, 50 * 10**6):
        body = odom_from_map @ truth_at(times, poses, ns) @ camera_to_base
        q = quaternion(body)
        odom = T["nav_msgs/msg/Odometry"](
            header=header(ns, "odom"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=body[0, 3], y=body[1, 3], z=body[2, 3]),
                    orientation=Quat(x=q[0], y=q[1], z=q[2], w=q[3])),
                covariance=cov),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=cov))
        out.append((ns, "/odom", "nav_msgs/msg/Odometry", odom))
        out.append((ns, "/tf", "tf2_msgs/msg/TFMessage", T["tf2_msgs/msg/TFMessage"](
            transforms=[transform(ns, "odom", "base_link", body)])))
    fx, fy, cx, cy = (float(calib[k]) for k in ("fx", "fy", "cx", "cy"))
    for ns, jpg, _, _ in frames:
        img = T["sensor_msgs/msg/CompressedImage"](
            header=header(ns, "camera_optical"), format="jpeg",
            data=np.frombuffer(jpg.read_bytes(), dtype=np.uint8))
        out.append((ns, "/camera/image/compressed", "sensor_msgs/msg/CompressedImage", img))
        info = T["sensor_msgs/msg/CameraInfo"](
            header=header(ns, "camera_optical"), height=int(calib["height"]), width=int(calib["width"]),
            distortion_model="plumb_bob", d=np.zeros(5, dtype=np.float64),
            k=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64),
            r=np.eye(3).reshape(-1),
            p=np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], dtype=np.float64),
            binning_x=0, binning_y=0,
            roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
        out.append((ns, "/camera/camera_info", "sensor_msgs/msg/CameraInfo", info))
    out.sort(key=lambda m: m[0])
    return ts, out


def write_robot_bag(out: Path, ts, messages, plugin):
    with Ros2Writer(out, version=8, storage_plugin=plugin) as w:
        connections = {}
        for ns, topic, msgtype, msg in messages:
            if topic not in connections:
                connections[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(connections[topic], ns, ts.serialize_cdr(msg, msgtype))


def write_robot(out: Path, loop: Path, frames):
    ts, messages = robot_messages(loop, frames)
    write_robot_bag(out / "robot", ts, messages, StoragePlugin.MCAP)
    # SQLite, split in two at the middle image as `ros2 bag record
    # --max-bag-duration` would: two files, one metadata.yaml listing both.
    middle = frames[len(frames) // 2][0]
    halves = [[m for m in messages if m[0] < middle], [m for m in messages if m[0] >= middle]]
    db3 = out / "robot_db3"
    db3.mkdir()
    files = []
    for k, half in enumerate(halves):
        part = out / f"robot_db3.part{k}"
        write_robot_bag(part, ts, half, StoragePlugin.SQLITE3)
        meta = yaml.safe_load((part / "metadata.yaml").read_text())
        (db3_file,) = part.glob("*.db3")
        name = f"robot_db3_{k}.db3"
        shutil.move(db3_file, db3 / name)
        info = meta["rosbag2_bagfile_information"]
        files.append((name, info))
        if k == 0:
            merged = meta
        shutil.rmtree(part)
    info = merged["rosbag2_bagfile_information"]
    info["relative_file_paths"] = [name for name, _ in files]
    info["files"] = [dict(part["files"][0], path=name) for name, part in files]
    info["message_count"] = sum(part["message_count"] for _, part in files)
    counts = {}
    for _, part in files:
        for topic in part["topics_with_message_count"]:
            name = topic["topic_metadata"]["name"]
            counts.setdefault(name, dict(topic, message_count=0))["message_count"] += topic["message_count"]
    info["topics_with_message_count"] = list(counts.values())
    info["duration"] = {"nanoseconds": messages[-1][0] - messages[0][0]}
    (db3 / "metadata.yaml").write_text(yaml.safe_dump(merged, sort_keys=False))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("loop", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--every", type=int, default=1)
    parser.add_argument("--limit", type=int)
    args = parser.parse_args()
    frames = read_loop(args.loop, args.every, args.limit)
    args.out.mkdir(parents=True, exist_ok=True)
    write_folder(args.out / "folder", frames)
    write_ros2(args.out / "ros2", frames)
    write_ros1(args.out / "drive.bag", frames)
    write_tum(args.out / "tum", frames)
    write_euroc(args.out / "euroc", frames)
    write_kitti(args.out / "kitti", frames)
    write_robot(args.out, args.loop, frames)
    print(f"make_recordings: {len(frames)} frames in 8 forms under {args.out}")


if __name__ == "__main__":
    main()
