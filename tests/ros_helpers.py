"""Small ROS 1 / ROS 2 bags written with rosbags' own writers, from semmap frames (for the rosbag reader's tests)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from semmap.datasets._ros_images import encode_compressed_depth
from semmap.types import Frame, invert_pose, rot_to_quat_xyzw

RGB, DEPTH, INFO = "/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw", "/camera/color/camera_info"


class BagWriter:
    """One bag of either ROS version with typed message builders (``kind``: ros1 | sqlite3 | mcap)."""

    def __init__(self, path: Path, kind: str) -> None:
        self.ros1 = kind == "ros1"
        self.store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in self.store.types:  # ROS 1's store lacks it; recorded bags carry it
            self.store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                                   "tf2_msgs/msg/TFMessage"))
        self.types = self.store.types
        if self.ros1:
            self.writer = Writer1(path)
        else:
            plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer2(path, version=9, storage_plugin=plugin)
        self.connections: dict[str, object] = {}

    def __enter__(self) -> BagWriter:
        self.writer.open()
        return self

    def __exit__(self, *exc) -> None:
        self.writer.close()

    def header(self, stamp: float, frame_id: str):
        Time = self.types["builtin_interfaces/msg/Time"]
        Header = self.types["std_msgs/msg/Header"]
        sec = int(np.floor(stamp))
        time = Time(sec=sec, nanosec=round((stamp - sec) * 1e9))
        return Header(seq=0, stamp=time, frame_id=frame_id) if self.ros1 else Header(stamp=time, frame_id=frame_id)

    def write(self, topic: str, msg, stamp: float) -> None:
        kind = msg.__msgtype__
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, kind, typestore=self.store)
        data = self.store.serialize_ros1(msg, kind) if self.ros1 else self.store.serialize_cdr(msg, kind)
        self.writer.write(self.connections[topic], round(stamp * 1e9), data)

    # ----------------------------------------------------------------- messages
    def image(self, stamp: float, frame_id: str, pixels: np.ndarray, encoding: str):
        h, w = pixels.shape[:2]
        big = encoding.endswith("_be")
        encoding = encoding.removesuffix("_be")
        data = np.ascontiguousarray(pixels)
        if big:
            data = data.astype(data.dtype.newbyteorder(">"))
        raw = data.view(np.uint8).reshape(-1)
        return self.types["sensor_msgs/msg/Image"](header=self.header(stamp, frame_id), height=h, width=w,
                                                   encoding=encoding, is_bigendian=int(big),
                                                   step=raw.size // h, data=raw)

    def compressed(self, stamp: float, frame_id: str, payload: bytes, fmt: str):
        return self.types["sensor_msgs/msg/CompressedImage"](header=self.header(stamp, frame_id), format=fmt,
                                                             data=np.frombuffer(payload, np.uint8))

    def camera_info(self, stamp: float, frame_id: str, frame: Frame):
        cam = frame.intrinsics
        k = np.array([cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1], np.float64)
        p = np.array([cam.fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0], np.float64)
        roi = self.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                             do_rectify=False)
        fields = {"D" if self.ros1 else "d": np.zeros(5), "K" if self.ros1 else "k": k,
                  "R" if self.ros1 else "r": np.eye(3).ravel(), "P" if self.ros1 else "p": p}
        return self.types["sensor_msgs/msg/CameraInfo"](header=self.header(stamp, frame_id), height=cam.height,
                                                        width=cam.width, distortion_model="plumb_bob", **fields,
                                                        binning_x=0, binning_y=0, roi=roi)

    def transform(self, stamp: float, parent: str, child: str, T: np.ndarray):
        g = self.types
        x, y, z, w = rot_to_quat_xyzw(T[:3, :3])
        tf = g["geometry_msgs/msg/Transform"](translation=g["geometry_msgs/msg/Vector3"](x=T[0, 3], y=T[1, 3],
                                                                                         z=T[2, 3]),
                                              rotation=g["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))
        return g["geometry_msgs/msg/TransformStamped"](header=self.header(stamp, parent), child_frame_id=child,
                                                       transform=tf)

    def tf(self, transforms: Sequence):
        return self.types["tf2_msgs/msg/TFMessage"](transforms=list(transforms))

    def pose(self, T: np.ndarray):
        g = self.types
        x, y, z, w = rot_to_quat_xyzw(T[:3, :3])
        return g["geometry_msgs/msg/Pose"](position=g["geometry_msgs/msg/Point"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                                           orientation=g["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))

    def pose_stamped(self, stamp: float, parent: str, T: np.ndarray):
        return self.types["geometry_msgs/msg/PoseStamped"](header=self.header(stamp, parent), pose=self.pose(T))

    def odometry(self, stamp: float, parent: str, child: str, T: np.ndarray):
        g = self.types
        with_cov = g["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(T), covariance=np.zeros(36))
        twist = g["geometry_msgs/msg/TwistWithCovariance"](
            twist=g["geometry_msgs/msg/Twist"](linear=g["geometry_msgs/msg/Vector3"](x=0, y=0, z=0),
                                               angular=g["geometry_msgs/msg/Vector3"](x=0, y=0, z=0)),
            covariance=np.zeros(36))
        return g["nav_msgs/msg/Odometry"](header=self.header(stamp, parent), child_frame_id=child, pose=with_cov,
                                          twist=twist)


    def imu(self, stamp: float, frame_id: str, acceleration: np.ndarray):
        g = self.types
        zero = g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        acc = g["geometry_msgs/msg/Vector3"](x=float(acceleration[0]), y=float(acceleration[1]),
                                             z=float(acceleration[2]))
        return g["sensor_msgs/msg/Imu"](header=self.header(stamp, frame_id),
                                        orientation=g["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                                        orientation_covariance=np.zeros(9), angular_velocity=zero,
                                        angular_velocity_covariance=np.zeros(9), linear_acceleration=acc,
                                        linear_acceleration_covariance=np.zeros(9))


#: A fixed mounting of the camera on the robot body (for /tf chains and Odometry of the body).
T_BODY_CAM = np.array([[0.0, 0.0, 1.0, 0.1], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.3], [0, 0, 0, 1.0]])


def write_bag(path: Path, frames: Sequence[Frame], *, kind: str = "ros1", color: str = "rgb8",
              depth: str = "16UC1", poses: str = "tf", depth_offset: float = 0.0, drop_depth: Sequence[int] = (),
              camera_info: bool = True, imu: bool = False) -> Path:
    """Write ``frames`` as a bag: colour (``color``: rgb8 | bgr8 | mono8 | jpeg | png), depth (``depth``: 16UC1 |
    mono16 | 32FC1 | 32FC1_be | compressedDepth | png16), CameraInfo and poses (``poses``: tf (map -> odom ->
    base_link -> camera, the last in /tf_static) | pose (PoseStamped of the camera) | odometry (Odometry of the body
    plus /tf_static to the camera) | none). Depth stamps are shifted by ``depth_offset`` seconds; the depth of the
    frames in ``drop_depth`` is left out. ``imu``: an accelerometer on the body (``/imu``, frame base_link) reading
    gravity's specific force for a z-up world."""
    with BagWriter(path, kind) as bag:
        if poses in ("tf", "odometry"):
            bag.write("/tf_static", bag.tf([bag.transform(frames[0].timestamp, "base_link", "camera", T_BODY_CAM)]),
                      frames[0].timestamp)
        odom = np.eye(4)
        odom[:3, 3] = [1.0, -2.0, 0.0]
        for i, frame in enumerate(frames):
            t = frame.timestamp
            T_body = frame.T_world_cam @ invert_pose(T_BODY_CAM)
            if poses == "tf":
                bag.write("/tf", bag.tf([bag.transform(t, "map", "odom", odom),
                                         bag.transform(t, "odom", "base_link", invert_pose(odom) @ T_body)]), t)
            elif poses == "pose":
                bag.write("/camera/pose", bag.pose_stamped(t, "map", frame.T_world_cam), t)
            elif poses == "odometry":
                bag.write("/odom", bag.odometry(t, "map", "base_link", T_body), t)
            if camera_info:
                bag.write(INFO, bag.camera_info(t, "camera", frame), t)
            if imu:
                bag.write("/imu", bag.imu(t, "base_link", T_body[:3, :3].T @ np.array([0.0, 0.0, 9.81])), t)
            bag.write(RGB, _color_message(bag, frame, t, color), t)
            if i not in drop_depth:
                td = t + depth_offset
                bag.write(DEPTH if depth != "compressedDepth" else DEPTH + "/compressedDepth",
                          _depth_message(bag, frame, td, depth), td)
    return path


def _color_message(bag: BagWriter, frame: Frame, t: float, color: str):
    if color in ("jpeg", "png"):
        ok, data = cv2.imencode(f".{color}", cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR))
        assert ok
        return bag.compressed(t, "camera", data.tobytes(), f"rgb8; {color} compressed bgr8")
    pixels = {"rgb8": frame.rgb, "bgr8": frame.rgb[..., ::-1], "mono8": frame.rgb[..., 0]}[color]
    return bag.image(t, "camera", pixels, color)


def _depth_message(bag: BagWriter, frame: Frame, t: float, depth: str):
    mm = np.rint(frame.depth * 1000).astype(np.uint16)
    if depth == "compressedDepth":
        return bag.compressed(t, "camera", encode_compressed_depth(mm), "16UC1; compressedDepth png")
    if depth == "png16":
        ok, data = cv2.imencode(".png", mm)
        assert ok
        return bag.compressed(t, "camera", data.tobytes(), "16UC1; png compressed")
    if depth.startswith("32FC1"):
        metres = frame.depth.astype(np.float32)
        metres[metres == 0] = np.nan  # drivers mark invalid float depth as NaN
        return bag.image(t, "camera", metres, depth)
    return bag.image(t, "camera", mm, depth)
