"""Write ROS bags (ROS1 .bag or ROS2 mcap) from the frames of a gsslam dataset with rosbags' writers."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def _sec_nsec(t: float) -> tuple[int, int]:
    whole, _, frac = np.format_float_positional(float(t), unique=True, trim="0").partition(".")
    return int(whole), int((frac + "000000000")[:9])


def write_bag(
    path: Path,
    frames,
    kind: str = "ros1",
    compressed: bool = False,
    depth_dt: float = 0.004,
    depth_topic: str = "/camera/depth/image",
) -> Path:
    """Topics: /camera/rgb/image_color (rgb8 Image, or PNG CompressedImage), ``depth_topic`` (32FC1
    metres, stamped ``depth_dt`` after the image), /camera/rgb/camera_info, /imu (one sample per
    frame). Header stamps are the frames' timestamps; receive times equal the stamps."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE if kind == "mcap" else Stores.ROS1_NOETIC)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Image, Compressed = T["sensor_msgs/msg/Image"], T["sensor_msgs/msg/CompressedImage"]
    Info, Roi, Imu = (
        T["sensor_msgs/msg/CameraInfo"],
        T["sensor_msgs/msg/RegionOfInterest"],
        T["sensor_msgs/msg/Imu"],
    )
    Vec, Quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    ros1 = kind == "ros1"

    def header(t: float, frame: str, seq: int):
        s, n = _sec_nsec(t)
        kw = {"seq": seq} if ros1 else {}
        return Header(**kw, stamp=Time(sec=s, nanosec=n), frame_id=frame), s * 10**9 + n

    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        ser = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        ser = ts.serialize_cdr
    img_type = Compressed.__msgtype__ if compressed else Image.__msgtype__
    with writer:
        c_img = writer.add_connection("/camera/rgb/image_color", img_type, typestore=ts)
        c_dep = writer.add_connection(depth_topic, Image.__msgtype__, typestore=ts)
        c_inf = writer.add_connection("/camera/rgb/camera_info", Info.__msgtype__, typestore=ts)
        c_imu = writer.add_connection("/imu", Imu.__msgtype__, typestore=ts)
        for k, fr in enumerate(frames):
            h, w = fr.image.shape[:2]
            rgb = np.round(fr.image * 255).astype(np.uint8)
            hd, t_ns = header(fr.timestamp, "rgb", k)
            if compressed:
                ok, png = cv2.imencode(".png", rgb[..., ::-1])
                msg = Compressed(header=hd, format="rgb8; png compressed bgr8", data=png.reshape(-1))
            else:
                msg = Image(header=hd, height=h, width=w, encoding="rgb8", is_bigendian=0, step=3 * w,
                            data=rgb.reshape(-1))  # fmt: skip
            writer.write(c_img, t_ns, ser(msg, img_type))
            if fr.depth is not None:
                hd_d, td_ns = header(fr.timestamp + depth_dt, "depth", k)
                d = np.nan_to_num(fr.depth.astype("<f4"), nan=0.0)
                msg = Image(header=hd_d, height=h, width=w, encoding="32FC1", is_bigendian=0, step=4 * w,
                            data=d.view(np.uint8).reshape(-1))  # fmt: skip
                writer.write(c_dep, td_ns, ser(msg, Image.__msgtype__))
            if k == 0:
                i = fr.intrinsics
                K = np.array([i.fx, 0, i.cx, 0, i.fy, i.cy, 0, 0, 1], dtype=np.float64)
                P = np.array([i.fx, 0, i.cx, 0, 0, i.fy, i.cy, 0, 0, 0, 1, 0], dtype=np.float64)
                names = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
                mats = dict(zip(names, (np.zeros(5), K, np.eye(3).reshape(-1), P)))
                roi = Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
                msg = Info(header=hd, height=h, width=w, distortion_model="plumb_bob", **mats, binning_x=0,
                           binning_y=0, roi=roi)  # fmt: skip
                writer.write(c_inf, t_ns, ser(msg, Info.__msgtype__))
            cov = np.zeros(9)
            gyro, acc = Vec(x=0.1 * k, y=0.0, z=0.0), Vec(x=0.0, y=0.0, z=9.81)
            msg = Imu(header=hd, orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=cov,
                      angular_velocity=gyro, angular_velocity_covariance=cov,
                      linear_acceleration=acc, linear_acceleration_covariance=cov)  # fmt: skip
            writer.write(c_imu, t_ns + 1, ser(msg, Imu.__msgtype__))
    return path
