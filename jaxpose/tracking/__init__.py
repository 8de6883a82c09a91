"""Tracking: registration of a sequence of clouds, chained against keyframes and filtered,
and the target's dynamics identified from the result.

`track(clouds, dt, key=...)` registers each frame against a keyframe with the method core,
then runs an error-state Kalman filter on SO(3) × R³ that gives attitude, angular rate and
acceleration, and the position and velocity of the first cloud's plane-frame origin.
`identify(track, dt)` fits Euler's equations to the registrations: principal axes, inertia
ratios, rate and centre of mass, with a prediction past the data. `body_model(clouds, track,
dynamics)` fuses the registered clouds into a voxelised model in the principal frame, and
`track_against_model(clouds, track, dt)` registers every frame against that model as it grows.
"""

from ._against_model import (
    track_against_model as track_against_model,
)
from ._identify import (
    Dynamics as Dynamics,
)
from ._identify import (
    Orbit as Orbit,
)
from ._identify import (
    identify as identify,
)
from ._model import (
    body_model as body_model,
)
from ._track import (
    FILTER_BAD_MEASUREMENT as FILTER_BAD_MEASUREMENT,
)
from ._track import (
    FILTER_BAD_UPDATE as FILTER_BAD_UPDATE,
)
from ._track import (
    FILTER_NO_ESTIMATE as FILTER_NO_ESTIMATE,
)
from ._track import (
    FILTER_STATUS_NAME as FILTER_STATUS_NAME,
)
from ._track import (
    FILTER_UPDATED as FILTER_UPDATED,
)
from ._track import (
    Track as Track,
)
from ._track import (
    default_tracking_config as default_tracking_config,
)
from ._track import (
    track as track,
)
