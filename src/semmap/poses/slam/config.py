"""Settings of the built-in RGB-D SLAM (features, tracking, keyframes, local map, loop closure)."""

from __future__ import annotations

from dataclasses import dataclass, fields

from semmap.errors import ConfigError


@dataclass(frozen=True)
class SlamConfig:
    """Every knob of :class:`~semmap.poses.slam.RgbdSlam`; the defaults suit 640x480 Kinect-class sequences."""

    # --- features
    n_features: int = 1000  #: ORB keypoints per frame
    scale_factor: float = 1.2  #: ORB pyramid scale between levels
    n_levels: int = 8  #: ORB pyramid levels
    fast_threshold: int = 12  #: FAST corner threshold (lower finds corners in low-texture areas)
    subpixel: bool = True  #: refine keypoints of the three finest pyramid levels to sub-pixel corner positions
    grid_cells: tuple[int, int] = (8, 6)  #: (columns, rows) of the grid that spreads keypoints over the image
    min_depth: float = 0.2  #: metres; nearer depth readings are ignored
    max_depth: float = 6.0  #: metres; farther depth readings are ignored (noise grows with depth squared)
    depth_edge_ratio: float = 0.04  #: a keypoint whose nearby depth spread exceeds this fraction of its depth has none
    depth_edge_radius: int = 1  #: pixels; the depth spread is measured over a (2r+1)^2 window
    #: 1/m, standard deviation of a measured inverse depth: the Kinect's own (sigma_z ~ 0.002 z^2). The depth is what
    #: pins the rotation-translation ambiguity of a pose seen against far, similar-depth landmarks; 10x looser
    #: (0.02) left `slam-features` 2.1x less accurate over 12 simulated sequences, 4.08 against 3.46 cm on 7-Scenes
    depth_noise: float = 0.002
    # --- tracking
    search_radius: float = 12.0  #: pixels around a predicted landmark projection searched for a match
    max_descriptor_distance: int = 80  #: Hamming distance accepted for a match (of 256 bits)
    match_ratio: float = 0.9  #: best / second-best distance ratio in guided matching
    ransac_reprojection_error: float = 4.0  #: pixels, PnP RANSAC inlier threshold
    ransac_iterations: int = 100  #: PnP RANSAC iterations
    min_tracked: int = 25  #: fewer pose inliers than this and the frame is lost
    # --- keyframes and local map
    keyframe_min_frames: int = 0  #: frames at least between keyframes
    keyframe_max_frames: int = 30  #: a keyframe at least this often
    keyframe_tracked_ratio: float = 0.8  #: keyframe when inliers drop below this share of the reference keyframe's
    keyframe_close_points: int = 100  #: keyframe when fewer close landmarks than this are tracked ...
    keyframe_new_close_points: int = 70  #: ... and at least this many close keypoints with depth are new
    close_depth: float = 3.0  #: metres; "close" points for the keyframe criterion
    covisible_keyframes: int = 10  #: keyframes (by shared landmarks) whose landmarks form the local map
    local_ba: bool = True  #: refine the newest keyframes and their landmarks by windowed bundle adjustment
    ba_window: int = 6  #: keyframes optimised by local bundle adjustment
    ba_iterations: int = 3  #: Levenberg-Marquardt iterations of a local bundle adjustment
    global_ba: bool = True  #: one full bundle adjustment of all keyframes when the final trajectory is asked for
    global_ba_iterations: int = 10  #: Levenberg-Marquardt iterations of that final bundle adjustment
    landmark_min_found_ratio: float = 0.25  #: landmarks found in fewer than this share of the frames that saw them go
    # --- loop closure and relocalisation
    loop_closure: bool = True  #: detect revisits and correct the whole keyframe graph
    loop_min_keyframe_gap: int = 15  #: a loop candidate is at least this many keyframes older
    loop_min_inliers: int = 50  #: PnP inliers that confirm a loop
    retrieval_features: int = 300  #: strongest descriptors per keyframe used to find loop / relocalisation candidates
    loop_candidates: int = 3  #: best retrieval candidates verified geometrically
    reloc_min_inliers: int = 40  #: PnP inliers that confirm a relocalisation
    # --- dense (photometric + geometric) alignment, see semmap.poses.slam.dense
    #: where feature tracking fails, align the frame densely to the reference keyframe (or the last frame) and
    #: continue from there with a new keyframe instead of losing track (textureless views)
    dense_fallback: bool = True
    #: refine feature-tracked poses by dense alignment to their reference keyframe: "off", "keyframes" (only
    #: frames that become keyframes) or "frames" (every frame; ~12 ms/frame more at 640x480 on 2 cores with
    #: dense_scale 2). "frames" measured 2-4x more accurate on the simulated sequences and the same on 7-Scenes
    dense_refine: str = "frames"
    #: tie a refined keyframe to its reference keyframe by the dense relative pose in bundle adjustment
    dense_ba_factor: bool = True
    #: images are subsampled by this factor for dense alignment: 2 (half resolution) is ~4x faster than 1 and
    #: measured as accurate over a sequence (sim-loop ATE 0.5 cm vs 0.7-1.4 cm, sim-desk 0.13 vs 0.09 cm)
    dense_scale: int = 2
    dense_iterations: tuple[int, ...] = (6, 4, 2)  #: Gauss-Newton iterations per pyramid level, coarse to fine
    dense_min_fitness: float = 0.3  #: an alignment with fewer pixels in correspondence is rejected
    dense_max_correction: float = 0.08  #: metres; a refinement moving a feature pose further is rejected ...
    dense_max_correction_deg: float = 4.0  #: ... or rotating it more (degrees)
    dense_max_jump: float = 0.25  #: metres; a fallback alignment this far from the motion prediction is rejected ...
    dense_max_jump_deg: float = 20.0  #: ... or rotated this far (degrees)
    #: metres; translation standard deviation of a dense keyframe factor in BA (tight: on clean data the dense
    #: alignment is far more precise than far-away feature depth; 3 mm / 0.2 deg measured worse on sim-loop)
    dense_sigma: float = 0.0005
    dense_sigma_deg: float = 0.03  #: degrees; its rotation standard deviation

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or f.name in ("grid_cells", "dense_iterations", "dense_refine"):
                continue
            if not isinstance(value, (int, float)) or value != value or value < 0:
                raise ConfigError(f"SlamConfig.{f.name} must be a non-negative number, got {value!r}")
        positive = ("n_features", "n_levels", "search_radius", "max_depth", "ransac_iterations", "ba_window",
                    "keyframe_max_frames", "retrieval_features", "loop_candidates", "depth_noise", "dense_scale",
                    "dense_sigma", "dense_sigma_deg")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ConfigError(f"SlamConfig.{name} must be positive, got {getattr(self, name)!r}")
        if self.scale_factor <= 1.0:
            raise ConfigError(f"SlamConfig.scale_factor must be > 1, got {self.scale_factor}")
        if not 0.0 < self.match_ratio <= 1.0:
            raise ConfigError(f"SlamConfig.match_ratio must be in (0, 1], got {self.match_ratio}")
        if self.min_depth >= self.max_depth:
            raise ConfigError(f"SlamConfig.min_depth ({self.min_depth}) must be below max_depth ({self.max_depth})")
        if len(self.grid_cells) != 2 or min(self.grid_cells) < 1:
            raise ConfigError(f"SlamConfig.grid_cells must be two positive counts, got {self.grid_cells!r}")
        if self.dense_refine not in ("off", "keyframes", "frames"):
            raise ConfigError(f"SlamConfig.dense_refine must be 'off', 'keyframes' or 'frames', "
                              f"got {self.dense_refine!r}")
        if not self.dense_iterations or any(int(i) < 1 for i in self.dense_iterations):
            raise ConfigError(f"SlamConfig.dense_iterations must be positive per level, got {self.dense_iterations!r}")
        if self.min_tracked < 6:
            raise ConfigError(f"SlamConfig.min_tracked must be at least 6 (PnP needs them), got {self.min_tracked}")
