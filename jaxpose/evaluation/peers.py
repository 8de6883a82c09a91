"""Peer registration methods for comparison (optional extra `peers`; never used by the core).

Each peer maps (previous points, current points) — `(N, 3)` arrays in frame c, metres — to
the camera-frame motion (R, t) with current ≈ R · previous + t, starting from the identity
like jaxpose. [`available_peers`][] lists those whose library imports here, and why the
others do not (Open3D's wheel needs the system library libusb-1.0, for example).

Settings (ours, fixed for every pair; documented so the comparison can be rerun):

- small_gicp (`small_gicp.align`): downsampling 1 cm (about half the pixel spacing at
  5.5 m, so nearly every point is kept), correspondences up to 0.5 m, 100 iterations,
  2 threads; types ICP, PLANE_ICP and GICP.
- Open3D: point-to-point and point-to-plane ICP (normals from 20 neighbours within 8 cm),
  correspondences up to 0.5 m, 100 iterations; FGR and RANSAC global registration on FPFH
  features of a 2 cm voxel grid (radius 10 cm), reported as they come (no refine).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Peer = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

MAX_DISTANCE = 0.5
ITERATIONS = 100


def _small_gicp(kind: str) -> Peer:
    import small_gicp

    def align(prev: np.ndarray, curr: np.ndarray):
        result = small_gicp.align(
            np.asarray(curr, np.float64),
            np.asarray(prev, np.float64),
            registration_type=kind,
            downsampling_resolution=0.01,
            max_correspondence_distance=MAX_DISTANCE,
            max_iterations=ITERATIONS,
            num_threads=2,
        )
        T = np.asarray(result.T_target_source)
        return T[:3, :3], T[:3, 3]

    return align


def _open3d_cloud(points: np.ndarray, normals: bool = False):
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    if normals:
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.08, max_nn=20))
    return cloud


def _open3d_icp(plane: bool) -> Peer:
    import open3d as o3d

    reg = o3d.pipelines.registration
    method = reg.TransformationEstimationPointToPlane() if plane else reg.TransformationEstimationPointToPoint()

    def align(prev: np.ndarray, curr: np.ndarray):
        src, dst = _open3d_cloud(prev, plane), _open3d_cloud(curr, plane)
        criteria = reg.ICPConvergenceCriteria(max_iteration=ITERATIONS)
        T = np.asarray(reg.registration_icp(src, dst, MAX_DISTANCE, np.eye(4), method, criteria).transformation)
        return T[:3, :3], T[:3, 3]

    return align


def _open3d_global(kind: str) -> Peer:
    import open3d as o3d

    reg = o3d.pipelines.registration
    voxel = 0.02

    def features(points):
        cloud = _open3d_cloud(points).voxel_down_sample(voxel)
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        fpfh = reg.compute_fpfh_feature(cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        return cloud, fpfh

    def align(prev: np.ndarray, curr: np.ndarray):
        (src, f_src), (dst, f_dst) = features(prev), features(curr)
        if kind == "fgr":
            option = reg.FastGlobalRegistrationOption(maximum_correspondence_distance=1.5 * voxel)
            result = reg.registration_fgr_based_on_feature_matching(src, dst, f_src, f_dst, option)
        else:
            result = reg.registration_ransac_based_on_feature_matching(
                src,
                dst,
                f_src,
                f_dst,
                True,
                1.5 * voxel,
                reg.TransformationEstimationPointToPoint(False),
                3,
                [reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
                reg.RANSACConvergenceCriteria(100000, 0.999),
            )
        T = np.asarray(result.transformation)
        return T[:3, :3], T[:3, 3]

    return align


PEERS: dict[str, tuple[str, Callable[[], Peer]]] = {
    "small_gicp ICP": ("small_gicp", lambda: _small_gicp("ICP")),
    "small_gicp plane-ICP": ("small_gicp", lambda: _small_gicp("PLANE_ICP")),
    "small_gicp GICP": ("small_gicp", lambda: _small_gicp("GICP")),
    "Open3D point-to-point ICP": ("open3d", lambda: _open3d_icp(plane=False)),
    "Open3D point-to-plane ICP": ("open3d", lambda: _open3d_icp(plane=True)),
    "Open3D FGR (FPFH)": ("open3d", lambda: _open3d_global("fgr")),
    "Open3D RANSAC (FPFH)": ("open3d", lambda: _open3d_global("ransac")),
}
"""name → (the module it needs, a factory of the aligner)."""


def available_peers() -> tuple[dict[str, Peer], dict[str, str]]:
    """The peers that import here, and for the others the reason (the import error)."""
    found, missing, reasons = {}, {}, {}
    for name, (module, factory) in PEERS.items():
        if module not in reasons:
            try:
                __import__(module)
                reasons[module] = ""
            except (ImportError, OSError) as err:  # Open3D raises ImportError for a missing libusb
                reasons[module] = f"{type(err).__name__}: {err}"
        if reasons[module]:
            missing[name] = reasons[module]
        else:
            found[name] = factory()
    return found, missing


__all__ = ["PEERS", "available_peers"]
