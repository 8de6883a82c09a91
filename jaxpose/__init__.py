"""jaxpose: change of pose of an uncooperative, unknown-shape space target from two lidar
point clouds, by plane-intersection patterns (METHOD.md), in JAX.

Data flow, one stage per private module (the public names are re-exported here):

    sim/ (simulate) or load_cloud → Cloud → plane_frame → Problem (patterns, grids)
    → hard_score / soft_score → batched scoring → global search → refine → fine stage
    → estimate → tracking/ (track)

`jaxpose.evaluation` holds the reproduction, benchmarks and peers; it is not imported here.
"""

from ._cloud import Cloud as Cloud
from ._config import (
    Capacities as Capacities,
)
from ._config import (
    Config as Config,
)
from ._config import (
    FineStage as FineStage,
)
from ._config import (
    GlobalSearch as GlobalSearch,
)
from ._config import (
    Patterns as Patterns,
)
from ._config import (
    Refine as Refine,
)
from ._config import (
    RotationSearch as RotationSearch,
)
from ._config import (
    Thresholds as Thresholds,
)
from ._estimate import Estimate as Estimate
from ._estimate import Hypotheses as Hypotheses
from ._estimate import Status as Status
from ._estimate import estimate as estimate
from ._estimate_batch import estimate_batch as estimate_batch
from ._fine import RotationHold as RotationHold
from ._fine import SlideHold as SlideHold
from ._frame import PlaneFrame as PlaneFrame
from ._frame import plane_frame as plane_frame
from ._io import load_cloud as load_cloud
from ._io import save_cloud as save_cloud
from ._objective import hard_score as hard_score
from ._objective import soft_score as soft_score
from ._objective import to_moved_frame as to_moved_frame
from ._poses import (
    displacement_from_motion as displacement_from_motion,
)
from ._poses import (
    motion_from_displacement as motion_from_displacement,
)
from ._poses import (
    relative_motion as relative_motion,
)
from ._poses import (
    true_displacement as true_displacement,
)
from ._problem import Problem as Problem
from ._programs import disable_compile_cache as disable_compile_cache
from ._programs import enable_compile_cache as enable_compile_cache
from ._rotations import angles as angles
from ._rotations import rotation as rotation
from ._rotations import rotation_angle as rotation_angle
from .sim import Camera as Camera
from .sim import Tumble as Tumble
from .sim import simulate as simulate
from .sim import simulate_sequence as simulate_sequence
from .sim import targets as targets
from .tracking import Dynamics as Dynamics
from .tracking import Orbit as Orbit
from .tracking import Track as Track
from .tracking import body_model as body_model
from .tracking import identify as identify
from .tracking import track as track
from .tracking import track_against_model as track_against_model

__all__ = [
    "Camera",
    "Capacities",
    "Cloud",
    "Config",
    "Dynamics",
    "FineStage",
    "Orbit",
    "GlobalSearch",
    "Patterns",
    "Refine",
    "RotationSearch",
    "Status",
    "Thresholds",
    "Estimate",
    "Hypotheses",
    "RotationHold",
    "SlideHold",
    "PlaneFrame",
    "Problem",
    "Track",
    "Tumble",
    "angles",
    "body_model",
    "displacement_from_motion",
    "disable_compile_cache",
    "enable_compile_cache",
    "estimate",
    "estimate_batch",
    "hard_score",
    "identify",
    "load_cloud",
    "motion_from_displacement",
    "plane_frame",
    "relative_motion",
    "rotation",
    "rotation_angle",
    "save_cloud",
    "simulate",
    "simulate_sequence",
    "soft_score",
    "targets",
    "to_moved_frame",
    "track",
    "track_against_model",
    "true_displacement",
]
