"""Checkpoints of a run: its state after every N mapped frames (and on Ctrl-C) in the staging folder, and
``--resume`` continuing from the last one exactly.

A checkpoint is a versioned record of public state (:mod:`semmap.io.state`): every map's ``state()``, the
mapper's counters, the pose source's poses and the run record, each under its own stable names, with the
configuration and the frame it follows in the header. A checkpoint of another schema version or another
configuration is named in one line and the run starts from the first frame.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable

from semmap import __version__
from semmap.config import RunConfig
from semmap.errors import ConfigError, FormatError
from semmap.eval.run_report import RunRecord
from semmap.io.staged_run import StagedRun
from semmap.io.state import prefixed, read_checkpoint, section, write_checkpoint
from semmap.limits import check
from semmap.perception.schedule import SegmentationSchedule
from semmap.poses.frame_poses import FramePoses
from semmap.types import Frame

log = logging.getLogger("semmap")


def check_checkpoint_options(every: int, resume: bool, *, online: bool, objects: bool, batched: bool) -> None:
    """Refuse checkpoint options a run cannot honour, before anything is read."""
    check("every", every, "--checkpoint-every")
    if not (every or resume):
        return
    if online:
        raise ConfigError("--checkpoint-every / --resume work offline only (online, the tracker's state is not "
                          "saved)")
    if objects:
        raise ConfigError("--checkpoint-every / --resume do not support --instances yet (the object tracker's "
                          "state is not saved)")
    if batched:
        raise ConfigError("--checkpoint-every / --resume need --batch-size 1 (a batch reads frames ahead)")


class Checkpoints:
    """Saves the run's state every ``every`` mapped frames into ``staged`` and reads the last one back."""

    def __init__(self, staged: StagedRun, config: RunConfig, *, every: int) -> None:
        self.staged, self.config, self.every = staged, config, int(every)
        self._config = json.loads(config.to_json())

    def after_frame(self, frame: Frame, mapper, pose_of: FramePoses, record: RunRecord, *,
                    interrupted: bool) -> None:
        """Save when ``every`` frames were mapped since the last save, or the run is being interrupted."""
        if not self.every or not (len(record.poses) % self.every == 0 or interrupted):
            return
        mapper_meta, mapper_arrays = mapper.state()
        poses_meta, poses_arrays = pose_of.state()
        record_meta, record_arrays = record.state()
        header = {"semmap": __version__, "config": self._config, "frame_index": int(frame.index),
                  "frame_name": frame.name, "maps": [m.kind.value for m in mapper.maps], "mapper": mapper_meta,
                  "poses": poses_meta, "record": record_meta}
        arrays = {**prefixed("mapper", mapper_arrays), **prefixed("poses", poses_arrays),
                  **prefixed("record", record_arrays)}
        for i, m in enumerate(mapper.maps):
            arrays.update(prefixed(f"maps/{i}", m.state()))
        write_checkpoint(self.staged.checkpoint_path, header, arrays)

    def resume(self, mapper, new_pose_source: Callable[[], FramePoses]) -> tuple[FramePoses, RunRecord] | None:
        """Restore ``mapper`` (freshly built for this configuration) from the last checkpoint; the pose source
        and the record to continue with, or None (with a one-line warning) when there is none to resume from."""
        path = self.staged.checkpoint_path
        if not path.is_file():
            log.warning("--resume: no checkpoint in %s; starting from the first frame", self.staged.stage)
            return None
        try:
            header, arrays = read_checkpoint(path)
        except FormatError as exc:
            log.warning("--resume: the checkpoint cannot be used (%s); starting from the first frame", exc)
            return None
        if header.get("config") != self._config:
            log.warning("--resume: the checkpoint in %s is of another configuration; starting from the first frame",
                        self.staged.stage)
            return None
        try:
            pose_of, record = self._restore(header, arrays, mapper, new_pose_source)
        except (FormatError, KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"--resume: the checkpoint {path} does not fit this run ({type(exc).__name__}: {exc}); "
                              f"run again without --resume") from None
        log.info("resuming %s after frame %s", self.config.input.dataset, header["frame_name"])
        return pose_of, record

    def _restore(self, header: dict, arrays: dict, mapper, new_pose_source: Callable[[], FramePoses]):
        if header["maps"] != [m.kind.value for m in mapper.maps]:
            raise FormatError(f"maps {header['maps']}, this run builds {[m.kind.value for m in mapper.maps]}")
        for i, m in enumerate(mapper.maps):
            m.restore(section(arrays, f"maps/{i}"))
        mapper.restore(header["mapper"], section(arrays, "mapper"))
        pose_of = new_pose_source()
        pose_of.restore(header["poses"], section(arrays, "poses"))
        s = self.config.semantics
        record = RunRecord.from_state(header["record"], section(arrays, "record"),
                                      SegmentationSchedule(every=s.segment_every, keyframes=s.keyframes))
        return pose_of, record
