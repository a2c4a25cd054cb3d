"""Checkpoints of a run: the state after every N mapped frames (and on Ctrl-C) in the staging folder, and
``--resume`` continuing from the last one exactly."""

from __future__ import annotations

import dataclasses

from semmap.errors import ConfigError
from semmap.eval.run_report import RunRecord
from semmap.io.staged_run import StagedRun
from semmap.types import Frame


def check_checkpoint_options(every: int, resume: bool, *, online: bool, objects: bool, batched: bool) -> None:
    """Refuse checkpoint options a run cannot honour, before anything is read."""
    if every < 0:
        raise ConfigError(f"--checkpoint-every must be 0 (off) or a number of frames, got {every}")
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

    def __init__(self, staged: StagedRun, *, config_json: str, every: int) -> None:
        self.staged, self.config_json, self.every = staged, config_json, int(every)

    def load(self):
        """``(mapper, pose source, record, frame name)`` of the last checkpoint of this configuration, or None."""
        resumed = self.staged.load_checkpoint(self.config_json)
        if resumed is None:
            return None
        (mapper, pose_of, record), _, name = resumed
        return mapper, pose_of, record, name

    def after_frame(self, frame: Frame, mapper, pose_of, record: RunRecord, *, interrupted: bool) -> None:
        """Save when ``every`` frames were mapped since the last save, or the run is being interrupted."""
        if not self.every or not (len(record.poses) % self.every == 0 or interrupted):
            return
        saved = dataclasses.replace(record, arrival={})  # (offline with batches of one: nothing is waiting)
        self.staged.save_checkpoint((mapper, pose_of, saved), config_json=self.config_json,
                                    frame_index=int(frame.index), frame_name=frame.name)
