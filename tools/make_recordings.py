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

The bags are written with `rosbags`, a ROS-free implementation of both bag
formats that owes nothing to HuMem's readers, so a test comparing
`humem eval` on each against the folder checks the readers against an
independent writer. Every format carries the same pixels (the PNGs and raw
images are the JPEGs decoded by Pillow, as HuMem's decoder decodes them)
and the same poses at the images' own times.

Usage: make_recordings.py LOOP_FOLDER OUT [--every N] [--limit M]
"""

import argparse
import io
import shutil
from pathlib import Path

import numpy as np
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
    print(f"make_recordings: {len(frames)} frames in 6 forms under {args.out}")


if __name__ == "__main__":
    main()
