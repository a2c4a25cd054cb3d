"""Built-in feature-based RGB-D SLAM in the spirit of ORB-SLAM2 (ORB features, local map tracking, local bundle
adjustment, loop closure and relocalisation with gtsam), exposed as the ``slam`` pose tracker."""

from semmap.poses.slam.config import SlamConfig
from semmap.poses.slam.dense_slam import DenseSlam, DenseSlamConfig
from semmap.poses.slam.system import RgbdSlam, SlamStats

__all__ = ["DenseSlam", "DenseSlamConfig", "RgbdSlam", "SlamConfig", "SlamStats"]
