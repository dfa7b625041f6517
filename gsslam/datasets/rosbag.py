"""ROS recordings (ROS1 ``.bag``, ROS2 bag folders with sqlite3 or mcap storage, single ``.mcap`` /
``.db3`` files) read with the pure-Python ``rosbags`` package (extra ``ros``: ``pip install gsslam[ros]``).

Topics, each a loader kwarg (CLI: ``--dataset-arg image_topic=/camera/rgb/image_color``):

- ``image_topic``: ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage``. Default: the only image
  topic whose name does not contain "depth"; with several, the error lists them.
- ``depth_topic``: a depth ``Image`` (``16UC1``/``mono16`` in millimetres, ``32FC1`` in metres, per
  ROS REP 118; ``depth_scale=`` overrides the factor) or a ``compressedDepth`` image. Default: the only
  image topic with "depth" in its name, else none. Each frame gets the nearest depth within ``max_dt``
  seconds; frames without one are dropped (as for TUM). ``with_depth=False`` ignores depth.
- ``camera_info_topic``: ``sensor_msgs/CameraInfo`` (default: the only one). Its first message gives
  K and the plumb_bob distortion. ``intrinsics=`` / ``intrinsics_file=`` (our YAML or a ROS
  camera_info YAML) take precedence. Distorted images are undistorted once (frames carry K, no
  distortion).
- ``imu_topic``: ``sensor_msgs/Imu`` (default: the only one); :meth:`RosbagDataset.imu` returns its
  samples. The pipeline does not use them yet.

Frame timestamps are the image headers' stamps (``sec.nanosec`` parsed as one decimal, so a stamp
written from a TUM timestamp reads back as the same float64), or the bag's receive time when a
header stamp is zero. ``gt_path=`` a TUM trajectory file gives ground truth. Frames are decoded on
demand: the constructor reads only the message headers' stamps.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import cv2
import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.datasets.common import (
    FrameGroundTruth,
    associate_nearest,
    load_intrinsics_yaml,
    normalize_index,
    read_tum_trajectory,
)
from gsslam.datasets.image_io import Undistorter, to_rgb_float
from gsslam.types import CameraIntrinsics, Frame, Trajectory

log = logging.getLogger(__name__)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMU = "sensor_msgs/msg/Imu"
# encoding -> (dtype, channels, channel order of a colour image)
_ENCODINGS = {
    "rgb8": ("u1", 3, "rgb"),
    "bgr8": ("u1", 3, "bgr"),
    "rgba8": ("u1", 4, "rgb"),
    "bgra8": ("u1", 4, "bgr"),
    "rgb16": ("u2", 3, "rgb"),
    "bgr16": ("u2", 3, "bgr"),
    "mono8": ("u1", 1, ""),
    "8uc1": ("u1", 1, ""),
    "mono16": ("u2", 1, ""),
    "16uc1": ("u2", 1, ""),
    "32fc1": ("f4", 1, ""),
}


class RosbagError(DatasetError):
    """A ROS bag cannot be opened, lacks a topic, or holds messages gsslam cannot decode."""


def _import_rosbags():
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise RosbagError(
            "reading ROS bags needs the 'rosbags' package: pip install 'gsslam[ros]' (or pip install rosbags)"
        ) from None
    return AnyReader, Stores, get_typestore


def _stamp(msg, logtime_ns: int) -> float:
    st = getattr(getattr(msg, "header", None), "stamp", None)
    if st is not None and (st.sec or st.nanosec):
        return float(f"{int(st.sec)}.{int(st.nanosec):09d}")  # one correctly rounded decimal
    return float(f"{logtime_ns // 10**9}.{logtime_ns % 10**9:09d}")


def decode_image(msg, msgtype: str, topic: str) -> np.ndarray:  # -> [H, W] or [H, W, C], BGR for colour
    """An ``Image`` / ``CompressedImage`` message as the array ``cv2.imread(..., IMREAD_UNCHANGED)`` gives."""
    if msgtype == COMPRESSED:
        buf = np.frombuffer(bytes(msg.data), np.uint8)
        if "compresseddepth" in msg.format.lower():
            buf = buf[12:]  # image_transport's compressedDepth: a 12-byte config header, then the PNG
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise RosbagError(f"{topic}: cannot decode a compressed image of format {msg.format!r}")
        return img
    enc = msg.encoding.lower()
    if enc not in _ENCODINGS:
        raise RosbagError(
            f"{topic}: image encoding {msg.encoding!r} is not supported; use one of {sorted(_ENCODINGS)}"
        )
    dtype, ch, order = _ENCODINGS[enc]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    raw = np.frombuffer(bytes(msg.data), np.uint8)
    if raw.size < h * step or step < w * ch * dt.itemsize:
        raise RosbagError(
            f"{topic}: image data has {raw.size} bytes for {w}x{h} {msg.encoding} (step {step})"
        )
    rows = raw[: h * step].reshape(h, step)[:, : w * ch * dt.itemsize]
    img = np.ascontiguousarray(rows).view(dt).reshape(h, w, ch).astype(dt.newbyteorder("="))
    if ch == 1:
        return img[:, :, 0]
    if order == "rgb":  # to OpenCV's BGR(A)
        img = img[:, :, [2, 1, 0, 3][:ch]]
    return img


def _intrinsics_from_camera_info(msg, topic: str) -> CameraIntrinsics:
    K = np.asarray(msg.k if hasattr(msg, "k") else msg.K, dtype=np.float64).reshape(-1)  # ROS2 / ROS1 names
    D = np.asarray(msg.d if hasattr(msg, "d") else msg.D, dtype=np.float64).reshape(-1)
    model = getattr(msg, "distortion_model", "") or ""
    if len(K) != 9 or K[0] <= 0:
        raise RosbagError(
            f"{topic}: CameraInfo has no valid K; pass intrinsics_file= (a camera_info YAML works)"
        )
    if np.any(D) and model not in ("plumb_bob", "rational_polynomial"):
        raise RosbagError(f"{topic}: distortion model {model!r} is not supported; pass rectified images")
    dist = tuple(float(d) for d in D) if np.any(D) else ()
    fx, fy, cx, cy = (float(K[k]) for k in (0, 4, 2, 5))
    return CameraIntrinsics(fx, fy, cx, cy, int(msg.width), int(msg.height), dist)


class RosbagDataset:
    """A ROS1/ROS2/mcap recording; see the module docstring for the kwargs."""

    def __init__(
        self,
        path: str | Path,
        *,
        image_topic: str | None = None,
        depth_topic: str | None = None,
        camera_info_topic: str | None = None,
        imu_topic: str | None = None,
        intrinsics: CameraIntrinsics | None = None,
        intrinsics_file: str | Path | None = None,
        depth_scale: float | None = None,
        with_depth: bool = True,
        max_dt: float = 0.02,
        gt_path: str | Path | None = None,
    ) -> None:
        AnyReader, Stores, get_typestore = _import_rosbags()
        self.root = Path(path)
        self.name = self.root.stem
        self.max_dt = float(max_dt)
        self._depth_scale = depth_scale
        self._lock = threading.Lock()
        try:
            self._reader = AnyReader([self.root], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self._reader.open()
        except Exception as e:  # rosbags raises its own reader errors and OSError
            raise RosbagError(f"cannot open ROS bag {self.root}: {e}") from None
        conns = self._reader.connections
        topics = {c.topic: c for c in conns}
        images = sorted({c.topic for c in conns if c.msgtype in (IMAGE, COMPRESSED)})
        image_topic = image_topic or self._only([t for t in images if "depth" not in t.lower()], "image")
        depth_default = [t for t in images if "depth" in t.lower()]
        if with_depth and depth_topic is None and len(depth_default) == 1:
            depth_topic = depth_default[0]
        for t in (image_topic, depth_topic, camera_info_topic, imu_topic):
            if t is not None and t not in topics:
                raise RosbagError(f"{self.root}: no topic {t!r}; topics: {', '.join(sorted(topics))}")
        self._image_conn = topics[image_topic]
        self.has_depth = bool(with_depth and depth_topic)
        self._depth_conn = topics[depth_topic] if self.has_depth else None
        self._imu_conn = topics[imu_topic] if imu_topic else self._optional(conns, IMU)

        if intrinsics is None and intrinsics_file is not None:
            intrinsics = load_intrinsics_yaml(Path(intrinsics_file))
        if intrinsics is None:
            info = topics[camera_info_topic] if camera_info_topic else self._optional(conns, CAMERA_INFO)
            if info is None:
                raise RosbagError(
                    f"{self.root}: no sensor_msgs/CameraInfo topic; pass intrinsics_file= (CLI: "
                    "--intrinsics; our YAML or a ROS camera_info YAML) or camera_info_topic="
                )
            for c, _, raw in self._reader.messages(connections=[info]):
                intrinsics = _intrinsics_from_camera_info(
                    self._reader.deserialize(raw, c.msgtype), info.topic
                )
                break
        self._undistort = Undistorter(intrinsics)
        self.intrinsics = self._undistort.intrinsics_out

        img_t, self._img_ref = self._index(self._image_conn)
        if len(img_t) == 0:
            raise RosbagError(f"{self.root}: topic {image_topic} has no messages")
        order = np.argsort(img_t, kind="stable")
        img_t, self._img_ref = img_t[order], [self._img_ref[k] for k in order]
        self._depth_ref: list = [None] * len(img_t)
        if self._depth_conn is not None:
            d_t, d_ref = self._index(self._depth_conn)
            match = associate_nearest(img_t, d_t, self.max_dt) if len(d_t) else np.full(len(img_t), -1)
            keep = np.flatnonzero(match >= 0)
            if len(keep) < len(img_t):
                log.warning("%s: %d of %d images have no depth within %s s; dropped", self.root,
                            len(img_t) - len(keep), len(img_t), self.max_dt)  # fmt: skip
            if len(keep) == 0:
                raise RosbagError(f"{self.root}: no image has a depth message within {self.max_dt} s")
            img_t, self._img_ref = img_t[keep], [self._img_ref[k] for k in keep]
            self._depth_ref = [d_ref[match[k]] for k in keep]
        self._times = img_t
        traj: Trajectory | None = read_tum_trajectory(Path(gt_path), "ground truth") if gt_path else None
        self._gt = FrameGroundTruth.by_time(traj, self._times, self.max_dt)
        log.info("rosbag %s: %d frames from %s, depth=%s", self.name, len(self), image_topic, depth_topic)

    @staticmethod
    def _only(topics: list[str], what: str) -> str:
        if len(topics) != 1:
            found = ", ".join(topics) or "none"
            raise RosbagError(f"cannot pick the {what} topic: found {found}; pass {what}_topic=")
        return topics[0]

    @staticmethod
    def _optional(conns, msgtype: str):
        cands = {c.topic: c for c in conns if c.msgtype == msgtype}
        return next(iter(cands.values())) if len(cands) == 1 else None

    def _index(self, conn) -> tuple[np.ndarray, list[tuple[int, int]]]:
        """Header stamps [N] and (receive time ns, rank among messages at that time) per message."""
        stamps, refs, last, rank = [], [], None, 0
        for c, t_ns, raw in self._reader.messages(connections=[conn]):
            msg = self._reader.deserialize(raw, c.msgtype)
            rank = rank + 1 if t_ns == last else 0
            last = t_ns
            stamps.append(_stamp(msg, t_ns))
            refs.append((t_ns, rank))
        return np.array(stamps, dtype=np.float64), refs

    def _read(self, conn, ref: tuple[int, int]):
        t_ns, rank = ref
        with self._lock:
            for k, (c, _, raw) in enumerate(
                self._reader.messages(connections=[conn], start=t_ns, stop=t_ns + 1)
            ):
                if k == rank:
                    return self._reader.deserialize(raw, c.msgtype)
        raise RosbagError(f"{self.root}: message at {t_ns} ns on {conn.topic} vanished")

    def __len__(self) -> int:
        return len(self._times)

    def timestamps(self) -> list[float]:
        return self._times.tolist()

    def __getitem__(self, index: int) -> Frame:
        i = normalize_index(index, len(self))
        conn = self._image_conn
        image = decode_image(self._read(conn, self._img_ref[i]), conn.msgtype, conn.topic)
        image = self._undistort.image(to_rgb_float(image, conn.topic))
        depth = None
        if self._depth_ref[i] is not None:
            dc = self._depth_conn
            raw = decode_image(self._read(dc, self._depth_ref[i]), dc.msgtype, dc.topic)
            if raw.ndim != 2:
                raise RosbagError(f"{dc.topic}: depth images must have one channel, got {raw.shape}")
            scale = (
                self._depth_scale
                if self._depth_scale is not None
                else (1.0 if raw.dtype.kind == "f" else 1e-3)
            )
            d = raw.astype(np.float32) * np.float32(scale) if scale != 1.0 else raw.astype(np.float32)
            d[~np.isfinite(d) | (d <= 0)] = np.nan
            if d.shape != image.shape[:2]:
                raise RosbagError(f"{dc.topic}: depth is {d.shape[::-1]} but images are {image.shape[1::-1]}")
            depth = self._undistort.depth(d)
        return Frame(i, float(self._times[i]), image, self.intrinsics, depth, self._gt.pose(i))

    def imu(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """IMU samples: timestamps [N] s, angular velocity [N, 3] rad/s, linear acceleration [N, 3] m/s^2."""
        if self._imu_conn is None:
            return None
        ts, gyro, acc = [], [], []
        with self._lock:
            for c, t_ns, raw in self._reader.messages(connections=[self._imu_conn]):
                m = self._reader.deserialize(raw, c.msgtype)
                ts.append(_stamp(m, t_ns))
                gyro.append((m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z))
                acc.append((m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z))
        return np.array(ts), np.array(gyro).reshape(-1, 3), np.array(acc).reshape(-1, 3)

    def ground_truth(self) -> Trajectory | None:
        return self._gt.trajectory

    def ground_truth_at_frames(self) -> Trajectory | None:
        return self._gt.at_frames(self._times)

    def close(self) -> None:
        self._reader.close()
