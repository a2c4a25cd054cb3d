"""Built-in RGB-D SLAM: the dense SLAM (``slam``: dense odometry, ORB loop closure and relocalisation, keyframe pose
graph) and the feature SLAM in the spirit of ORB-SLAM2 (``slam-orb``: ORB features, local map tracking, local
bundle adjustment, loop closure and relocalisation with gtsam)."""

from semmap.poses.slam.config import SlamConfig
from semmap.poses.slam.dense_slam import DenseSlam, DenseSlamConfig
from semmap.poses.slam.system import RgbdSlam, SlamStats

__all__ = ["DenseSlam", "DenseSlamConfig", "RgbdSlam", "SlamConfig", "SlamStats"]
