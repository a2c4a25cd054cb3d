"""Live viewing with rerun: per frame the colour, depth and class images, the camera and its trajectory, and every
``map_every`` frames the map's occupied voxels in class colours; a finished map file opened the same way.

The pipeline talks to a :class:`Visualizer`; :class:`NoVisualizer` does nothing, so the frame loop has no ``if``.
Entity layout: ``world/camera`` (pose, pinhole), ``world/camera/image/{rgb,depth,classes}``, ``world/trajectory``,
``world/map``; timelines ``frame`` (frame index) and ``time`` (the frame's timestamp, seconds).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
import threading
import time
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from semmap.errors import ConfigError, FormatError, OutputError, SemmapError
from semmap.files.outputs import OutputKind, check_outputs, shown_path
from semmap.types import EMPTY_LABEL, Frame, LabelSet, MapCloud, TopKProbs, muted_grey

LOG = logging.getLogger("semmap")
#: Default number of frames between two logs of the whole map.
DEFAULT_MAP_EVERY = 10
#: JPEG quality of logged colour images (rerun stores them compressed: ~50 KB instead of 900 KB at 640x480).
JPEG_QUALITY = 85
APPLICATION_ID = "semmap"


class MapLike(Protocol):
    """What the visualizer reads from a map: its occupied voxels and classes."""

    label_set: LabelSet | None

    def cloud(self) -> MapCloud: ...


class Visualizer(Protocol):
    """Receives a run's frames and map as they are built."""

    def log_frame(self, frame: Frame, T_world_cam: np.ndarray, semantics: TopKProbs | None, map_: MapLike) -> None:
        """One integrated frame (and, when due, the map as it stands)."""
        ...

    def finish(self, map_: MapLike) -> None:
        """The final map; flush and close."""
        ...

    def show_objects(self, objects: Callable[[], list], label_set: LabelSet | None) -> None:
        """Log the object map too, whenever the map is logged: ``objects()`` gives its objects (``lo``, ``hi``,
        ``id``, ``class_id``)."""
        ...


class NoVisualizer:
    """The visualizer of a run without a viewer: every call does nothing."""

    def log_frame(self, frame: Frame, T_world_cam: np.ndarray, semantics: TopKProbs | None, map_: MapLike) -> None:
        pass

    def finish(self, map_: MapLike) -> None:
        pass

    def show_objects(self, objects: Callable[[], list], label_set: LabelSet | None) -> None:
        pass


def viewer_executable() -> str | None:
    """The rerun viewer installed beside this Python (its ``bin/``), which need not be on PATH."""
    beside = Path(sys.executable).with_name("rerun")
    return str(beside) if beside.is_file() else shutil.which("rerun")


#: Free space a recording's folder needs before rerun's file writer starts (it blocks, or deadlocks, on a full
#: disk instead of failing).
MIN_RECORDING_SPACE = 64 << 20
#: Seconds of one wait for rerun's flush, and the most all waits may take: rerun's own flush waits forever, and
#: on a full disk its file writer stops (a flush then never ends, and closing the stream hangs too).
FLUSH_STEP_S, FLUSH_TIMEOUT_S = 1.0, 120.0
#: Seconds closing a recording stream may take before its writer counts as stuck.
DISCONNECT_TIMEOUT_S = 5.0


def check_recording_space(path: Path, *, needed: int | None = None) -> None:
    """Refuse, in one line before logging starts, a recording whose folder is not writable or nearly full (and
    stop one whose disk fills up while it is written, with ``needed`` the space left to keep)."""
    folder, needed = path.parent, MIN_RECORDING_SPACE if needed is None else needed
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"cannot write the rerun recording {shown_path(path)}: {folder} is not writable; write it "
                          f"elsewhere")
    free = shutil.disk_usage(folder).free
    if free < needed:
        raise ConfigError(f"cannot write the rerun recording {shown_path(path)}: only {free / 2**20:.1f} MB free in "
                          f"{folder}; a recording needs at least {needed >> 20} MB (rerun would hang on a full "
                          f"disk); free some space or write it elsewhere")


def recording_failure(exc: Exception, save: str | Path | None) -> SemmapError:
    """One line for rerun's error while writing or sending a recording: the file named when there is one (a full
    disk says so), the viewer only when there is no file."""
    reason = (str(exc).splitlines() or [type(exc).__name__])[0]
    if save is None:
        return ConfigError(f"rerun viewer unreachable: {reason}")
    folder, advice = Path(save).parent, "write it elsewhere"
    if _nearly_full(folder):
        free = shutil.disk_usage(folder).free
        reason = f"no space left on the device ({free / 2**20:.1f} MB free in {folder})"
        advice = "free some space or write it elsewhere"
    return OutputError(f"cannot write the rerun recording {shown_path(save)}: {reason}; {advice}")


def close_recording(rec, save: str | Path | None = None) -> None:
    """Flush and close, never hanging: a recording file the disk refused, or a viewer that went away, is one line
    naming it, not a traceback or a wait without end."""
    try:
        _flush(rec, save)
    except RuntimeError as exc:
        _disconnect(rec)
        raise recording_failure(exc, save) from None
    if not _disconnect(rec):
        raise recording_failure(RuntimeError("rerun did not close the recording"), save)


def _flush(rec, save: str | Path | None) -> None:
    """``rec.flush()`` in short waits: given up when the recording file stopped growing on a nearly full disk (a
    stopped writer), or after :data:`FLUSH_TIMEOUT_S`."""
    deadline = time.monotonic() + FLUSH_TIMEOUT_S
    size = _file_size(save)
    while True:
        try:
            rec.flush(timeout_sec=FLUSH_STEP_S)
            return
        except RuntimeError as exc:
            if "timed out" not in str(exc).lower():
                raise
            now = _file_size(save)
            grown, size = now != size, now
            if time.monotonic() > deadline or (save is not None and not grown and _nearly_full(Path(save).parent)):
                raise RuntimeError(f"rerun's writer stopped ({exc})") from None


def _file_size(path: str | Path | None) -> int:
    try:
        return os.stat(path).st_size if path is not None else 0
    except OSError:
        return 0


def _nearly_full(folder: Path) -> bool:
    try:
        return shutil.disk_usage(folder).free < MIN_RECORDING_SPACE
    except OSError:
        return False


def _disconnect(rec) -> bool:
    """Close the stream on a helper thread: False when rerun's writer is stuck (its exit hook, which would wait for
    it forever, is then dropped, so the process still ends)."""
    closing = threading.Thread(target=rec.disconnect, name="rerun-disconnect", daemon=True)
    closing.start()
    closing.join(DISCONNECT_TIMEOUT_S)
    if closing.is_alive():
        import rerun as rr

        rr.unregister_shutdown()
        return False
    return True


def quiet_rerun_log() -> None:
    """rerun's own log lines (a full disk prints several ERROR lines) off unless ``RUST_LOG`` asks for them:
    semmap reports a failed recording itself, in one line. Must run before rerun is first imported."""
    os.environ.setdefault("RUST_LOG", "off")


def partial_recording(save: str | Path) -> Path:
    """Where a recording is written until it is complete (then renamed to ``save``, so a failed one never replaces
    an earlier file)."""
    return Path(save).with_name(f".{Path(save).name}.partial")


def open_recording(name: str, *, save: str | Path | None, spawn: bool, viewer_for: str = "--rerun-spawn"):
    """A rerun recording stream writing to ``save`` (.rrd) and/or a newly spawned viewer."""
    quiet_rerun_log()
    import rerun as rr
    from rerun.sinks import spawn as spawn_viewer

    rec = rr.RecordingStream(APPLICATION_ID)
    sinks = []
    if save is not None:
        Path(save).parent.mkdir(parents=True, exist_ok=True)
        check_recording_space(Path(save))
        sinks.append(rr.FileSink(str(save)))
    if spawn:
        if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise ConfigError(f"{viewer_for}: cannot open a rerun viewer: no display (DISPLAY / WAYLAND_DISPLAY "
                              "unset); write a recording instead (semmap run --rerun FILE.rrd, semmap view MAP "
                              "--save FILE.rrd) and open it with `rerun FILE.rrd` where there is a screen")
        executable = viewer_executable()
        if executable is None:
            raise ConfigError("--rerun-spawn: no rerun viewer found (pip install rerun-sdk puts `rerun` beside "
                              "python); write a recording with --rerun FILE and open it elsewhere")
        try:
            spawn_viewer(connect=False, executable_path=executable, recording=rec)
        except RuntimeError as exc:
            raise ConfigError(f"--rerun-spawn: cannot start the rerun viewer: {str(exc).splitlines()[0]}") from None
        sinks.append(rr.GrpcSink())
    try:
        rec.set_sinks(*sinks)  # (opens the file: "Failed to create file" when the disk or the system refuses it)
    except RuntimeError as exc:
        raise recording_failure(exc, save) from None
    rec.send_recording_name(name)
    return rec


def _unlink(path: Path | None) -> None:
    if path is not None:
        with contextlib.suppress(OSError):
            path.unlink()


def class_colors(cloud: MapCloud, label_set: LabelSet | None) -> np.ndarray:
    """(M, 3) uint8 voxel colours: the class colour where the top class is a real one, the observed colour in grey
    where it is unknown (0) or missing, so classified things stand out."""
    if label_set is None:
        return cloud.colors
    top = cloud.labels
    ok = (top < len(label_set)) & (top != 0)
    out = muted_grey(cloud.colors)
    out[ok] = label_set.colors[top[ok]]
    return out


class RerunVisualizer:
    """Logs a run to a rerun recording: saved to ``save`` (.rrd), and/or streamed to a spawned viewer."""

    def __init__(self, *, save: str | Path | None = None, spawn: bool = False, map_every: int = DEFAULT_MAP_EVERY,
                 recording_name: str = "semmap run") -> None:
        quiet_rerun_log()
        import rerun as rr

        if save is None and not spawn:
            raise ConfigError("rerun logging needs a file to save to or a viewer to spawn")
        if map_every < 1:
            raise ConfigError(f"--rerun-map-every must be at least 1, got {map_every}")
        self._rr = rr
        self.save = None if save is None else Path(save)
        self._partial = None if save is None else partial_recording(save)  # renamed to ``save`` by finish()
        self._drop_partial = weakref.finalize(self, _unlink, self._partial)  # a failed run leaves no partial file
        try:
            self.rec = open_recording(recording_name, save=self._partial, spawn=spawn)
        except BaseException:
            self._drop_partial()
            raise
        self.map_every = map_every
        self._objects: tuple[Callable[[], list], LabelSet | None] | None = None
        self._positions: list[np.ndarray] = []
        self._frames = 0
        self._last_map_frame = -1
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def log_frame(self, frame: Frame, T_world_cam: np.ndarray, semantics: TopKProbs | None, map_: MapLike) -> None:
        rr, rec = self._rr, self.rec
        if self._partial is not None:  # stop in one line before rerun's writer meets a full disk (it would hang)
            try:
                check_recording_space(self._partial, needed=MIN_RECORDING_SPACE // 4)
            except ConfigError:
                _disconnect(rec)
                self._drop_partial()
                raise
        if self._frames == 0 and map_.label_set is not None:
            log_classes(rec, map_.label_set)
        rec.set_time("frame", sequence=int(frame.index))
        rec.set_time("time", duration=float(frame.timestamp))
        cam = frame.intrinsics
        T = np.asarray(T_world_cam, np.float64)
        rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        rec.log("world/camera/image", rr.Pinhole(image_from_camera=cam.K, resolution=[cam.width, cam.height],
                                                 camera_xyz=rr.ViewCoordinates.RDF))
        rec.log("world/camera/image/rgb", rr.Image(frame.rgb).compress(jpeg_quality=JPEG_QUALITY))
        depth_mm = np.clip(np.rint(frame.depth * 1000.0), 0, 65535).astype(np.uint16)
        rec.log("world/camera/image/depth", rr.DepthImage(depth_mm, meter=1000.0))
        if semantics is not None:
            rec.log("world/camera/image/classes", rr.SegmentationImage(semantics.labels[..., 0]))
        self._positions.append(T[:3, 3].copy())
        self._frames += 1
        if self._frames % self.map_every == 0:
            self._log_trajectory()
            self._log_map(map_)

    def finish(self, map_: MapLike) -> None:
        if self._frames and self._last_map_frame != self._frames:
            self._log_trajectory()
            self._log_map(map_)
        try:
            close_recording(self.rec, self._partial)
            if self._partial is not None:
                os.replace(self._partial, self.save)
        finally:
            self._drop_partial()

    def _log_trajectory(self) -> None:
        if len(self._positions) >= 2:
            self.rec.log("world/trajectory", self._rr.LineStrips3D([np.stack(self._positions)],
                                                                  colors=[(255, 140, 0)]))

    def show_objects(self, objects: Callable[[], list], label_set: LabelSet | None) -> None:
        self._objects = (objects, label_set)

    def _log_map(self, map_: MapLike) -> None:
        self._last_map_frame = self._frames
        log_cloud(self.rec, "world/map", map_.cloud(), map_.label_set)
        if self._objects is not None:
            log_objects(self.rec, "world/objects", self._objects[0](), self._objects[1])


def log_classes(rec, label_set: LabelSet) -> None:
    """Class names and colours for everything under ``world`` (class images and voxel class ids)."""
    import rerun as rr

    rec.log("world", rr.AnnotationContext([(i, name, tuple(int(c) for c in color)) for i, (name, color) in
                                           enumerate(zip(label_set.names, label_set.colors, strict=True))]),
            static=True)


def log_cloud(rec, entity: str, cloud: MapCloud, label_set: LabelSet | None) -> None:
    """Occupied voxels as boxes in class colours (class ids kept, so the viewer can show their names)."""
    import rerun as rr

    half = 0.5 * cloud.resolution
    class_ids = np.where(cloud.labels == EMPTY_LABEL, 0, cloud.labels).astype(np.uint16)
    rec.log(entity, rr.Boxes3D(centers=cloud.centers.astype(np.float32), half_sizes=[half, half, half],
                               colors=class_colors(cloud, label_set), class_ids=class_ids, fill_mode="solid"))


def log_objects(rec, entity: str, objects: list, label_set: LabelSet | None) -> None:
    """Objects as boxes around their points, in their class colour, labelled ``id class``."""
    import rerun as rr

    objects = [o for o in objects if np.isfinite(o.lo).all() and np.isfinite(o.hi).all()]
    if not objects:
        rec.log(entity, rr.Clear(recursive=False))
        return
    lo, hi = np.stack([o.lo for o in objects]), np.stack([o.hi for o in objects])
    ids = np.array([o.class_id for o in objects], np.uint16)
    names = label_set.names if label_set is not None else ()
    labels = [f"{o.id} {names[o.class_id] if o.class_id < len(names) else o.class_id}" for o in objects]
    colors = (label_set.colors[np.minimum(ids, len(label_set) - 1)] if label_set is not None
              else np.full((len(objects), 3), 200, np.uint8))
    rec.log(entity, rr.Boxes3D(centers=((lo + hi) / 2).astype(np.float32),
                               half_sizes=((hi - lo) / 2).astype(np.float32), colors=colors, labels=labels,
                               class_ids=ids))


def get_visualizer(output, *, name: str = "semmap run") -> Visualizer:
    """The visualizer an ``OutputConfig`` asks for (``--rerun FILE``, ``--rerun-spawn``), else the null one."""
    if output.rerun is None and not output.rerun_spawn:
        return NoVisualizer()
    return RerunVisualizer(save=output.rerun, spawn=output.rerun_spawn, map_every=output.rerun_map_every,
                           recording_name=name)


# --------------------------------------------------------------------------------------------------
# A finished map
# --------------------------------------------------------------------------------------------------
def map_file_cloud(path: str | Path) -> tuple[MapCloud, LabelSet | None]:
    """Occupied voxels of a ``.semmap`` (any map), ``.ply``, ``.ot`` or ``.bt`` file (a ``.bt`` has no colour:
    grey by height)."""
    path = Path(path)
    if path.suffix == ".semmap":
        from semmap.io.map_files import load_map

        m = load_map(path)
        return m.cloud(), m.label_set
    if path.suffix == ".ply":
        from semmap.io.objects import is_objects_ply, objects_ply_cloud
        from semmap.io.ply import read_ply

        return (objects_ply_cloud(path) if is_objects_ply(path) else read_ply(path)), None
    if path.suffix not in (".ot", ".bt"):
        raise FormatError(f"{path}: semmap view opens .semmap, .ply, .ot and .bt files")
    from semmap.io.octomap_files import read_octomap
    from semmap.keys import keys_to_coords

    leaves = read_octomap(path)
    keys, leaf_of = leaves.expand()
    keep = leaves.occupied()[leaf_of]
    centers = keys_to_coords(keys[keep], leaves.resolution)
    if leaves.colors is not None:
        colors = leaves.colors[leaf_of[keep]]
    else:
        z = centers[:, 2]
        shade = (60 + 180 * (z - z.min()) / max(float(np.ptp(z)), 1e-9)) if len(z) else z
        colors = np.repeat(shade.astype(np.uint8)[:, None], 3, axis=1)
    n = len(centers)
    cloud = MapCloud(centers, np.ascontiguousarray(colors, np.uint8), np.full(n, EMPTY_LABEL, np.uint16),
                     np.zeros(n, np.float32), leaves.resolution)
    return cloud, None


def view_map(path: str | Path, *, save: str | Path | None = None, spawn: bool = True) -> int:
    """Log a finished map file, or a product semmap writes beside maps (``rerun_products``: mesh, ESDF, scene
    graph, grid, costmap, diff, objects, trajectory), to rerun (saved to ``save`` and/or a spawned viewer); returns
    the count of voxels (or of what the product shows).

    ``save`` is checked against the map before it is read, written beside under a temporary name and renamed into
    place once complete (never the map itself, never a device)."""
    quiet_rerun_log()
    import rerun as rr

    from semmap.viz.rerun_products import is_product_file, log_product

    partial = None
    if save is not None:
        check_outputs([("--save", save, OutputKind.FILE)], [("MAP", path)])
        partial = partial_recording(save)
    product = is_product_file(Path(path))
    if not product:
        cloud, label_set = map_file_cloud(path)
    try:
        rec = open_recording(f"semmap view {Path(path).name}", save=partial, spawn=spawn, viewer_for=f"view {path}")
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if product:
            n = log_product(rec, Path(path))
        else:
            if label_set is not None:
                log_classes(rec, label_set)
            log_cloud(rec, "world/map", cloud, label_set)
            n = len(cloud)
        close_recording(rec, partial)
        if partial is not None:
            os.replace(partial, save)
    finally:
        if partial is not None:
            partial.unlink(missing_ok=True)
    return n

