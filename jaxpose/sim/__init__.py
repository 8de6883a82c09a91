"""Simulation: the stage before a cloud exists.

A time-of-flight `Camera`, `targets` (box assemblies and triangle meshes), `simulate` (one
ray-cast cloud in camera frame c), the torque-free / gravity-gradient attitude and
Clohessy–Wiltshire dynamics that drive a `Tumble`, `simulate_sequence`, and the paper's
scenarios (`paper_pair`, `capture_pair`, `rotated_pair`). The method never imports this
package: it sees only clouds.
"""

from . import targets as targets
from ._camera import Camera as Camera
from ._scenarios import (
    PAPER_POSES as PAPER_POSES,
)
from ._scenarios import (
    PAPER_T as PAPER_T,
)
from ._scenarios import (
    Pair as Pair,
)
from ._scenarios import (
    capture_pair as capture_pair,
)
from ._scenarios import (
    capture_pairs as capture_pairs,
)
from ._scenarios import (
    paper_pair as paper_pair,
)
from ._scenarios import (
    paper_pairs as paper_pairs,
)
from ._scenarios import (
    paper_pose as paper_pose,
)
from ._scenarios import (
    rotated_pair as rotated_pair,
)
from ._sequence import Sequence as Sequence
from ._sequence import Tumble as Tumble
from ._sequence import simulate_sequence as simulate_sequence
from ._sequence import tumble_poses as tumble_poses
from ._simulate import simulate as simulate
