"""Multi-object tracking of instances from frame to frame: DeepSORT (Kalman filter on boxes, Mahalanobis gating,
appearance matching cascade, IoU matching) as the object-oriented SLAM paper uses it (its eqs. 1-7)."""

from semmap.perception.tracking.deepsort import DeepSort, DeepSortParams, TrackState

__all__ = ["DeepSort", "DeepSortParams", "TrackState"]
