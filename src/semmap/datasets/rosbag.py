"""ROS 1 bags (``.bag``) and ROS 2 bags (a folder with ``metadata.yaml`` and sqlite3 or mcap storage), read with
``rosbags`` (no ROS installation).

Colour and depth come from two image topics (``sensor_msgs/Image`` or ``CompressedImage``), associated one to one by
nearest header timestamp within ``max_time_diff`` (as TUM's associate.py); intrinsics from a ``CameraInfo`` topic;
poses from ``/tf`` + ``/tf_static`` (``world_frame`` -> ``camera_frame``) or from a ``PoseStamped`` / ``Odometry`` /
``TransformStamped`` topic, looked up at the colour image's timestamp. Depth is taken to be registered to the colour
image (same size and pixels), as ``aligned_depth_to_color`` or ``depth_registered`` topics are.

The bag is read twice: once for the time stamps, intrinsics and transforms, then once more while frames are
iterated, so only the images of the frames being paired are held in memory.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.datasets._ros_images import decode_color, decode_depth
from semmap.datasets._ros_tf import TransformTree
from semmap.datasets.accelerometer import up_at
from semmap.datasets.base import (
    FormatEntry,
    SkippedFrame,
    UnreadableFileError,
    check_image_size,
    select_frames,
    skip_frame,
)
from semmap.datasets.tum import associate
from semmap.errors import DatasetError
from semmap.files.safe import regular_file_size
from semmap.types import CameraIntrinsics, Frame, make_pose, quat_xyzw_to_rot

LOG = logging.getLogger("semmap")

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
IMU_TYPE = "sensor_msgs/msg/Imu"
TF_TYPE = "tf2_msgs/msg/TFMessage"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry", "geometry_msgs/msg/TransformStamped",
              "geometry_msgs/msg/PoseWithCovarianceStamped")
TF_TOPICS = ("/tf", "/tf_static")
#: Suffixes that file or folder names of bags carry.
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
#: The first bytes of a ROS 1 bag (format 2.0, the only one rosbags reads).
ROS1_MAGIC = b"#ROSBAG V2.0\n"
#: Largest ``metadata.yaml`` of a ROS 2 bag read.
MAX_METADATA_BYTES = 16 * 2**20
#: Intrinsics assumed when a bag has no CameraInfo (TUM's recommended default, scaled to the image size).
DEFAULT_FOCAL_AT_640 = 525.0


def is_rosbag(path: Path) -> bool:
    """A ROS 1 bag file, a ROS 2 bag folder (``metadata.yaml``) or a ROS 2 storage file inside one."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix in BAG_SUFFIXES


def bag_paths(path: Path) -> list[Path]:
    """What ``AnyReader`` opens for ``path``: the ``.bag`` file, or the ROS 2 folder (also from a file inside it)."""
    if not path.exists():
        raise DatasetError(f"{path}: does not exist")
    error = lambda reason: DatasetError(f"{path}: {reason}")  # noqa: E731
    if path.is_dir():
        for entry in path.iterdir():  # rosbags opens every storage file: none may be a FIFO or a device
            if not entry.is_dir():
                size = regular_file_size(entry, what="ROS bag file", error=lambda r, e=entry: DatasetError(f"{e}: {r}"))
                if entry.name == "metadata.yaml" and size > MAX_METADATA_BYTES:
                    raise DatasetError(f"{entry}: {size:,} bytes is too large for a bag's metadata")
    else:
        regular_file_size(path, what="ROS bag", error=error)
        if path.suffix == ".bag":
            with open(path, "rb") as f:  # rosbags reads the first *line*: a file without line breaks is read whole
                magic = f.read(len(ROS1_MAGIC))
            if magic != ROS1_MAGIC:
                raise DatasetError(f"{path}: not a ROS 1 bag (starts with {magic!r}, expected {ROS1_MAGIC!r})")
    if path.is_file() and path.suffix in (".mcap", ".db3"):
        if not (path.parent / "metadata.yaml").is_file():
            raise DatasetError(f"{path}: a ROS 2 storage file needs the bag folder's metadata.yaml beside it")
        return [path.parent]
    return [path]


@dataclass(frozen=True)
class _Stamped:
    """One image message: its position among the topic's messages and its time (header stamp, else bag time)."""

    index: int
    stamp: float


@dataclass(frozen=True)
class _Pair:
    index: int
    name: str
    stamp: float
    rgb: int
    depth: int
    T_world_cam: np.ndarray | None
    pose_reason: str
    up_cam: np.ndarray | None = None


def _stamp_of(msg, bag_time_ns: int) -> float:
    header = getattr(msg, "header", None)
    if header is not None:
        s = float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)
        if s > 0:
            return s
    return 1e-9 * bag_time_ns


def _transform_matrix(translation, rotation) -> np.ndarray:
    q = [float(rotation.x), float(rotation.y), float(rotation.z), float(rotation.w)]
    if not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
        raise ValueError("rotation quaternion is zero or not finite")
    t = [float(translation.x), float(translation.y), float(translation.z)]
    if not np.isfinite(t).all():
        raise ValueError("translation is not finite")
    return make_pose(quat_xyzw_to_rot(q), t)


def _pose_of_message(msg) -> tuple[str, str, np.ndarray]:
    """(parent frame, child frame or "", T_parent_child) of a pose-carrying message."""
    kind = msg.__msgtype__
    if kind == "geometry_msgs/msg/TransformStamped":
        return msg.header.frame_id, msg.child_frame_id, _transform_matrix(msg.transform.translation,
                                                                          msg.transform.rotation)
    pose = msg.pose.pose if kind in ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped") \
        else msg.pose
    child = getattr(msg, "child_frame_id", "")
    return msg.header.frame_id, child, _transform_matrix(pose.position, pose.orientation)


class RosbagDataset:
    """RGB-D frames from a ROS 1 or ROS 2 bag; topics and frames found automatically where unambiguous."""

    def __init__(self, path: str | Path, *, rgb_topic: str | None = None, depth_topic: str | None = None,
                 camera_info_topic: str | None = None, pose_topic: str | None = None, world_frame: str | None = None,
                 camera_frame: str | None = None, max_time_diff: float = 0.02, stride: int = 1,
                 max_frames: int | None = None, labels_dir=None, strict: bool = False,
                 imu_topic: str | None = None) -> None:
        from rosbags.highlevel import AnyReader

        if labels_dir is not None:
            raise DatasetError(f"{path}: label folders are matched to files by name; a ROS bag has no frame files "
                               "(use --segmenter instead)")
        self._path = Path(path)
        self._paths = bag_paths(self._path)
        self._max_time_diff = float(max_time_diff)
        self._strict = strict
        self._skipped: list[SkippedFrame] = []
        self._open = AnyReader
        self._pose_parent: str | None = None
        self._pose_child = "<camera>"
        try:
            with AnyReader(self._paths) as reader:
                topics = {c.topic: c.msgtype for c in reader.connections}
                self._rgb_topic = rgb_topic or self._choose_image_topic(topics, depth=False)
                self._depth_topic = depth_topic or self._choose_image_topic(topics, depth=True)
                for option, topic in (("--rgb-topic", self._rgb_topic), ("--depth-topic", self._depth_topic)):
                    self._check_topic(topics, topic, IMAGE_TYPES, option)
                if self._rgb_topic == self._depth_topic:
                    raise DatasetError(f"{self._path}: {self._rgb_topic} is both the colour and the depth topic; "
                                       "name the other one with --rgb-topic or --depth-topic; image topics: "
                                       f"{_image_encodings(reader, topics)}")
                info_topic = camera_info_topic or self._choose_info_topic(topics)
                if info_topic is not None:
                    self._check_topic(topics, info_topic, (CAMERA_INFO_TYPE,), "--camera-info-topic")
                if pose_topic is not None:
                    self._check_topic(topics, pose_topic, POSE_TYPES, "--pose-topic")
                imus = [t for t, kind in topics.items() if kind == IMU_TYPE]
                self._imu_topic = imu_topic or (imus[0] if len(imus) == 1 else None)
                if imu_topic is not None:
                    self._check_topic(topics, imu_topic, (IMU_TYPE,), "imu_topic")
                index = self._index(reader, info_topic, pose_topic)
        except DatasetError:
            raise
        except Exception as exc:  # rosbags raises its own errors (and struct / KeyError ones) on damaged bags
            raise DatasetError(f"{self._path}: cannot read the bag: {type(exc).__name__}: {exc}") from None
        rgb, depth, info, tree, image_frame, self._imu = index
        if not rgb or not depth:
            empty = self._rgb_topic if not rgb else self._depth_topic
            raise DatasetError(f"{self._path}: topic {empty} has no messages")
        self._intrinsics = self._intrinsics_from(info, info_topic)
        self._pairs = select_frames(self._associate(rgb, depth, tree, pose_topic, world_frame,
                                                    camera_frame or image_frame), stride, max_frames)

    # ------------------------------------------------------------------ protocol
    @property
    def name(self) -> str:
        return self._path.stem if self._path.is_file() else self._path.resolve().name

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    @property
    def label_set(self):
        return None

    @property
    def skipped(self) -> list[SkippedFrame]:
        return self._skipped

    def __len__(self) -> int:
        return len(self._pairs)

    def __iter__(self) -> Iterator[Frame]:
        """Frames in colour-timestamp order, from one pass over the two image topics."""
        self._skipped.clear()
        if not self._pairs:
            return
        wanted = {self._rgb_topic: {p.rgb: k for k, p in enumerate(self._pairs)},
                  self._depth_topic: {p.depth: k for k, p in enumerate(self._pairs)}}
        images: dict[int, dict[str, object]] = {}
        failed: dict[int, tuple[str, str]] = {}
        next_pair = 0
        counters = {self._rgb_topic: 0, self._depth_topic: 0}
        try:
            with self._open(self._paths) as reader:
                connections = [c for c in reader.connections if c.topic in counters]
                for connection, _, raw in reader.messages(connections=connections):
                    topic = connection.topic
                    position = counters[topic]
                    counters[topic] += 1
                    k = wanted[topic].get(position)
                    if k is None:
                        continue
                    where = f"{self._path}:{topic}#{position}"
                    try:
                        msg = reader.deserialize(raw, connection.msgtype)
                        image = (decode_depth(msg, where) if topic == self._depth_topic
                                 else decode_color(msg, where))
                    except UnreadableFileError as exc:
                        failed[k] = (exc.path, exc.reason)
                        image = None
                    except DatasetError:
                        raise
                    except Exception as exc:  # a message the type system cannot decode: that frame only
                        failed[k] = (where, f"cannot decode message: {type(exc).__name__}: {exc}")
                        image = None
                    images.setdefault(k, {})[topic] = image
                    while next_pair < len(self._pairs) and len(images.get(next_pair, ())) == 2:
                        frame = self._frame(next_pair, images.pop(next_pair), failed.pop(next_pair, None))
                        next_pair += 1
                        if frame is not None:
                            yield frame
        except DatasetError:
            raise
        except Exception as exc:
            raise DatasetError(f"{self._path}: cannot read the bag: {type(exc).__name__}: {exc}") from None
        for k in range(next_pair, len(self._pairs)):
            pair = self._pairs[k]
            self._skip(pair.name, str(self._path), "message missing on the second pass over the bag")

    def _frame(self, k: int, images: dict, failure: tuple[str, str] | None) -> Frame | None:
        pair = self._pairs[k]
        if failure is not None:
            self._skip(pair.name, *failure)
            return None
        rgb, depth = images[self._rgb_topic], images[self._depth_topic]
        try:
            check_image_size(rgb, self._intrinsics, f"{self._path}:{self._rgb_topic}", "colour")
            check_image_size(depth, self._intrinsics, f"{self._path}:{self._depth_topic}", "depth")
        except UnreadableFileError as exc:
            self._skip(pair.name, exc.path, exc.reason)
            return None
        return Frame(index=pair.index, timestamp=pair.stamp, rgb=rgb, depth=depth, intrinsics=self._intrinsics,
                     T_world_cam=pair.T_world_cam, name=pair.name, up_cam=pair.up_cam)

    def _skip(self, name: str, path: str, reason: str) -> None:
        skip_frame(name, path, reason, self._skipped, strict=self._strict)

    # ------------------------------------------------------------------ first pass
    def _index(self, reader, info_topic: str | None, pose_topic: str | None):
        """Stamps of both image topics, the first CameraInfo, the transform tree, the images' frame id."""
        stamps: dict[str, list[_Stamped]] = {self._rgb_topic: [], self._depth_topic: []}
        info = None
        tree = TransformTree()
        image_frame = ""
        imu: list[tuple[float, float, float, float, str]] = []  # stamp, acceleration, frame id
        read = set(stamps) | {info_topic, pose_topic, self._imu_topic}
        if pose_topic is None:
            read |= set(TF_TOPICS)
        else:
            read.add("/tf_static")  # fixed extrinsics (body -> camera) still apply to a pose topic
        connections = [c for c in reader.connections if c.topic in read]
        for connection, bag_time, raw in reader.messages(connections=connections):
            topic = connection.topic
            msg = reader.deserialize(raw, connection.msgtype)
            if topic in stamps:
                stamps[topic].append(_Stamped(len(stamps[topic]), _stamp_of(msg, bag_time)))
                if topic == self._depth_topic and not image_frame:
                    image_frame = str(msg.header.frame_id)
            elif topic == info_topic:
                info = info or msg
            elif topic == pose_topic:
                self._add_pose(tree, msg, bag_time, topic)
            elif topic == self._imu_topic:
                a = msg.linear_acceleration
                imu.append((_stamp_of(msg, bag_time), float(a.x), float(a.y), float(a.z), str(msg.header.frame_id)))
            elif connection.msgtype == TF_TYPE:
                for transform in msg.transforms:
                    try:
                        T = _transform_matrix(transform.transform.translation, transform.transform.rotation)
                    except ValueError as exc:
                        LOG.warning("%s:%s: transform %s -> %s ignored: %s", self._path, topic,
                                    transform.header.frame_id, transform.child_frame_id, exc)
                        continue
                    tree.add(transform.header.frame_id, transform.child_frame_id, _stamp_of(transform, bag_time), T,
                             static=topic == "/tf_static")
        return stamps[self._rgb_topic], stamps[self._depth_topic], info, tree, image_frame, imu

    def _add_pose(self, tree: TransformTree, msg, bag_time: int, topic: str) -> None:
        """A pose-topic message as an edge of the tree (its child is the camera unless the message names one)."""
        try:
            parent, child, T = _pose_of_message(msg)
        except ValueError as exc:
            LOG.warning("%s:%s: pose at t=%.3f ignored: %s", self._path, topic, _stamp_of(msg, bag_time), exc)
            return
        self._pose_parent = parent or "world"
        self._pose_child = child or "<camera>"
        tree.add(self._pose_parent, self._pose_child, _stamp_of(msg, bag_time), T)

    # ------------------------------------------------------------------ choices
    def _choose_image_topic(self, topics: dict[str, str], *, depth: bool) -> str:
        """The one image topic that looks like depth (or colour); uncompressed preferred, registered depth
        preferred; otherwise a clear error listing the image topics."""
        images = [t for t, kind in topics.items() if kind in IMAGE_TYPES]
        chosen = [t for t in images if ("depth" in t.lower()) == depth]
        chosen = [t for t in chosen if topics[t] == IMAGE_TYPES[0]] or chosen  # raw over compressed
        if depth and len(chosen) > 1:
            chosen = [t for t in chosen if "aligned" in t or "registered" in t] or chosen
        if not depth and len(chosen) > 1:
            chosen = [t for t in chosen if "color" in t.lower() or "rgb" in t.lower()] or chosen
        if len(chosen) == 1:
            return chosen[0]
        what, option = ("depth", "--depth-topic") if depth else ("colour", "--rgb-topic")
        listing = ", ".join(f"{t} ({topics[t].split('/')[-1]})" for t in images) or "none"
        raise DatasetError(f"{self._path}: cannot tell which topic is the {what} image ({len(chosen)} candidates); "
                           f"name it with {option}; image topics: {listing}")

    def _choose_info_topic(self, topics: dict[str, str]) -> str | None:
        """The CameraInfo topic sharing the longest namespace with the depth topic (None when there is none)."""
        infos = [t for t, kind in topics.items() if kind == CAMERA_INFO_TYPE]
        if not infos:
            return None

        def shared(topic: str) -> int:
            a, b = topic.split("/")[:-1], self._depth_topic.split("/")
            return next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b)))

        return max(infos, key=lambda t: (shared(t), -len(t)))

    @staticmethod
    def _check_topic(topics: dict[str, str], topic: str, kinds: tuple[str, ...], option: str) -> None:
        if topic not in topics:
            listing = ", ".join(f"{t} ({k.split('/')[-1]})" for t, k in sorted(topics.items()))
            raise DatasetError(f"{option} {topic}: no such topic in the bag; topics: {listing}")
        if topics[topic] not in kinds:
            raise DatasetError(f"{option} {topic}: is {topics[topic]}, expected "
                               f"{' or '.join(k.split('/')[-1] for k in kinds)}")

    def _intrinsics_from(self, info, info_topic: str | None) -> CameraIntrinsics:
        if info is not None:
            K = np.asarray(getattr(info, "k", None) if hasattr(info, "k") else info.K, dtype=np.float64)
            fx, cx, fy, cy = K[0], K[2], K[4], K[5]
            w, h = int(info.width), int(info.height)
            if np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0 and w > 0 and h > 0:
                return CameraIntrinsics(w, h, float(fx), float(fy), float(cx), float(cy))
            LOG.warning("%s:%s: camera info is uncalibrated (K = %s, %dx%d)", self._path, info_topic,
                        K.round(3).tolist(), w, h)
        w, h = self._image_size()
        f = DEFAULT_FOCAL_AT_640 * w / 640
        LOG.warning("%s: no usable CameraInfo; assuming fx = fy = %.1f px, cx = %.1f, cy = %.1f for %dx%d images "
                    "(name one with --camera-info-topic)", self._path, f, (w - 1) / 2, (h - 1) / 2, w, h)
        return CameraIntrinsics(w, h, f, f, (w - 1) / 2, (h - 1) / 2)

    def _image_size(self) -> tuple[int, int]:
        with self._open(self._paths) as reader:
            connections = [c for c in reader.connections if c.topic == self._rgb_topic]
            for connection, _, raw in reader.messages(connections=connections):
                where = f"{self._path}:{self._rgb_topic}"
                try:
                    h, w = decode_color(reader.deserialize(raw, connection.msgtype), where).shape[:2]
                except UnreadableFileError:
                    continue
                return w, h
        raise DatasetError(f"{self._path}: no decodable colour image to take the camera size from")

    def _associate(self, rgb: list[_Stamped], depth: list[_Stamped], tree: TransformTree, pose_topic: str | None,
                   world_frame: str | None, camera_frame: str) -> list[_Pair]:
        """Colour/depth pairs within ``max_time_diff``, with the pose at the colour stamp."""
        for topic, items in ((self._rgb_topic, rgb), (self._depth_topic, depth)):
            times = np.array([s.stamp for s in items])
            repeats = int(len(times) - len(np.unique(times)))
            if repeats:
                LOG.warning("%s:%s: %d messages repeat an earlier timestamp; each is paired at most once",
                            self._path, topic, repeats)
        pairs_ij = associate([s.stamp for s in rgb], [s.stamp for s in depth], self._max_time_diff)
        if len(pairs_ij) < len(rgb):
            LOG.info("%s: %d of %d colour images have no depth image within %.3f s", self._path,
                     len(rgb) - len(pairs_ij), len(rgb), self._max_time_diff)
        if not pairs_ij:
            raise DatasetError(f"{self._path}: no colour image of {self._rgb_topic} has a depth image of "
                               f"{self._depth_topic} within {self._max_time_diff} s")
        world, camera = self._frames(tree, pose_topic, world_frame, camera_frame)
        gravity = self._gravity(tree, camera_frame)
        pairs = []
        for index, (i, j) in enumerate(pairs_ij):
            stamp = rgb[i].stamp
            T, reason = (None, "the bag has no poses") if world is None else \
                tree.lookup(world, camera, stamp, self._max_time_diff)
            up = None
            if gravity is not None:
                up = up_at(gravity[0], gravity[1], stamp)
                up = None if up is None else gravity[2] @ up
            pairs.append(_Pair(index, f"{stamp:.6f}", stamp, rgb[i].index, depth[j].index, T, reason, up))
        if world is not None and all(p.T_world_cam is None for p in pairs):
            LOG.warning("%s: no frame has a pose from %s to %s: %s", self._path, world, camera, pairs[0].pose_reason)
        return pairs

    def _gravity(self, tree: TransformTree, camera_frame: str
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The IMU's stamps, accelerations and the rotation from its frame into the camera's, or None (no IMU, or
        no transform between the two frames: said once)."""
        if not self._imu:
            return None
        stamps = np.array([r[0] for r in self._imu])
        readings = np.array([r[1:4] for r in self._imu])
        order = np.argsort(stamps, kind="stable")
        imu_frame = self._imu[0][4].lstrip("/")
        camera = (camera_frame or "").lstrip("/")
        if imu_frame in ("", camera):
            return stamps[order], readings[order], np.eye(3)
        root = tree.root_of(camera) if camera in tree else None
        t = float(stamps[order][0])
        T_root_cam, why = (None, f"camera frame {camera!r} is not in /tf") if root is None else \
            tree.lookup(root, camera, t, float("inf"))
        T_root_imu, why_imu = (None, why) if T_root_cam is None else tree.lookup(root, imu_frame, t, float("inf"))
        if T_root_imu is None:
            LOG.warning("%s:%s: no transform from the IMU frame %r to the camera (%s); its readings are not used",
                        self._path, self._imu_topic, imu_frame, why_imu)
            return None
        return stamps[order], readings[order], T_root_cam[:3, :3].T @ T_root_imu[:3, :3]

    def _frames(self, tree: TransformTree, pose_topic: str | None, world_frame: str | None, camera_frame: str
                ) -> tuple[str | None, str]:
        """(world frame or None when the bag has no poses, camera frame) for pose lookups."""
        if pose_topic is not None:
            if self._pose_parent is None:
                raise DatasetError(f"--pose-topic {pose_topic}: no usable pose in the bag")
            camera = self._pose_child
            if camera != "<camera>" and camera_frame and camera_frame.lstrip("/") in tree and \
                    tree.root_of(camera_frame) == tree.root_of(camera):
                camera = camera_frame  # a body pose plus static extrinsics to the camera
            return world_frame or self._pose_parent, camera
        if not tree.frames:
            return None, camera_frame
        if not camera_frame:
            raise DatasetError(f"{self._path}: the depth images name no frame_id; give --camera-frame (frames in "
                               f"/tf: {', '.join(tree.frames)})")
        if camera_frame.lstrip("/") not in tree:
            LOG.warning("%s: camera frame %r is not in /tf (frames: %s); frames have no pose", self._path,
                        camera_frame, ", ".join(tree.frames))
            return None, camera_frame
        world = world_frame or tree.root_of(camera_frame)
        if world.lstrip("/") not in tree:
            raise DatasetError(f"--world-frame {world}: not in /tf; frames: {', '.join(tree.frames)}")
        return world, camera_frame


def _image_encodings(reader, topics: dict[str, str]) -> str:
    """``topic (encoding)`` of every image topic, from its first message, for a message that must say which is
    colour and which is depth."""
    parts = []
    for topic, kind in sorted(topics.items()):
        if kind not in IMAGE_TYPES:
            continue
        encoding = "no messages"
        connections = [c for c in reader.connections if c.topic == topic]
        for connection, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            encoding = str(getattr(msg, "encoding", None) or getattr(msg, "format", "") or "unknown encoding")
            break
        parts.append(f"{topic} ({encoding})")
    return ", ".join(parts) or "none"


def _open_rosbag(path: Path, *, labels, raw_color: bool, ros: dict | None, **kwargs) -> RosbagDataset:
    if not Path(path).exists():
        raise DatasetError(f"{path}: ROS bag does not exist")
    return RosbagDataset(path, labels_dir=labels, **(ros or {}), **kwargs)


#: ROS 1 and ROS 2 bags (read by the ``rosbags`` package).
FORMAT = FormatEntry("rosbag", _open_rosbag, "ROS 1 .bag file or ROS 2 bag folder (colour, depth, CameraInfo, "
                     "/tf or a pose topic)", detect=is_rosbag, looks_for="metadata.yaml (ROS 2 bag)", folder=False)
