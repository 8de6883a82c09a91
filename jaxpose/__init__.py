"""jaxpose: change of pose of an uncooperative, unknown-shape space target from two lidar
point clouds, by plane-intersection patterns (METHOD.md), in JAX.

Data flow: `simulate` (or `load_cloud`) → `Cloud` → `plane_frame` → `Problem` (patterns, grids) →
`hard_score` / `soft_score` → `estimate` → `track` (sequences from `simulate_sequence`).
"""

from . import targets
from .camera import Camera
from .cloud import Cloud
from .config import Config
from .estimate import Estimate, estimate
from .frame import PlaneFrame, plane_frame
from .io import load_cloud, save_cloud
from .objective import hard_score, soft_score
from .poses import (
    displacement_from_motion,
    motion_from_displacement,
    relative_motion,
    true_displacement,
)
from .problem import Problem
from .rotations import angles, rotation, rotation_angle
from .sequence import Tumble, simulate_sequence
from .simulate import simulate
from .track import track

__all__ = [
    "Camera",
    "Cloud",
    "Config",
    "Estimate",
    "PlaneFrame",
    "Problem",
    "hard_score",
    "plane_frame",
    "soft_score",
    "angles",
    "displacement_from_motion",
    "estimate",
    "load_cloud",
    "save_cloud",
    "motion_from_displacement",
    "relative_motion",
    "rotation",
    "rotation_angle",
    "simulate",
    "simulate_sequence",
    "targets",
    "track",
    "true_displacement",
    "Tumble",
]
