"""Two views of a 1 m cube from a camera on +z (frame n, metres), for the capture stage's
tests: the faces each view turns towards the camera, the current one after a known motion."""

import math
from typing import NamedTuple

import numpy as np

from jaxpose.evaluation import realistic


class BoxViews(NamedTuple):
    """The cube's points and normals before (`P`, `N`) and after (`B`, `M`) the motion
    x ↦ `G` x + `xyz`, which of them face the `camera` in each view, and the motion."""

    P: np.ndarray
    N: np.ndarray
    B: np.ndarray
    M: np.ndarray
    seen_prev: np.ndarray
    seen_curr: np.ndarray
    G: np.ndarray
    xyz: np.ndarray
    camera: np.ndarray


def box_views(points_per_face: int, seed: int = 1) -> BoxViews:
    """`points_per_face` uniform points on each face, a 70° turn and a 25 cm shift."""
    rng = np.random.default_rng(seed)
    pts, nrm = [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            p = rng.uniform(-0.5, 0.5, (3, points_per_face))
            p[axis] = 0.5 * sign
            n = np.zeros((3, points_per_face))
            n[axis] = sign
            pts.append(p)
            nrm.append(n)
    P, N = np.concatenate(pts, 1), np.concatenate(nrm, 1)
    camera = np.array([0.3, -0.2, 5.0])
    G = np.asarray(realistic._axis_angle(np.array([1.0, 2.0, 0.5]), math.radians(70.0)))
    xyz = np.array([0.05, -0.12, 0.2])
    B, M = G @ P + xyz[:, None], G @ N
    seen_prev = np.sum(N * (camera[:, None] - P), axis=0) > 0
    seen_curr = np.sum(M * (camera[:, None] - B), axis=0) > 0
    return BoxViews(P, N, B, M, seen_prev, seen_curr, G, xyz, camera)
