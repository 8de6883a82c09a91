"""Body-frame models fused from the tracked tumbles of `experiments/identify.py` (issue 24).

For each case of the last `identify.py` run (its tracks in `results/identify_tracks.npz`):
the keyframes' clouds are simulated again with the same keys (the very clouds the tracker
registered), then fused with `jp.body_model` twice, with the tracked motions and with the true
ones, both in frame c at the first frame's time and with 1 cm voxels. Reported per case:

- the model's size (voxels) from each;
- how far the tracked model's points lie from the true-motion model (nearest neighbour, cm;
  median and 90th percentile): what the tracking's errors do to the model;
- for the targets built of boxes (N5, Chibis-M), each model's distance to the target's exact
  surface (cm; median and 90th percentile): the range noise averaged down, and the blur
  the tracking adds.

The tracked model in the principal frame (from `jp.identify`) is written as PLY to
`results/body_models/<case>.ply` (not committed).

    uv run python experiments/body_model.py  →  results/body_model.{json,md}
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from _common import RESULTS, write_json
from identify import CASES, DISTANCE, make_tumble
from scipy.spatial import cKDTree

import jaxpose as jp
from jaxpose.evaluation.model_fit import box_distance
from jaxpose.sim._sequence import tumble_poses
from jaxpose.sim.targets import Boxes
from jaxpose.tracking._identify import identify_tracked
from jaxpose.tracking._model import fuse_clouds

VOXEL = 0.01


def keyframe_clouds(case: str, index: int, frames: np.ndarray, dt: float, count: int):
    """The clouds of `frames` exactly as `identify.py` simulated them (same keys), and the true
    poses G^c_t, O_t of those frames."""
    key = jax.random.key(2000 + index)
    family = "n5" if case.startswith("n5") else case
    target = getattr(jp.targets, family)()
    tumble = make_tumble(case, jax.random.fold_in(key, 0))
    camera = jp.Camera.camcube2(noise_sigma=0.01, noise_range_ref=5.0)
    keys = jax.random.split(jax.random.fold_in(key, 1), count)[frames]
    times = jnp.arange(count)[frames] * dt
    G, p, _ = tumble_poses(tumble, times)
    clouds = jax.vmap(lambda R, t, k: jp.simulate(camera, target, R, t, k))(G, p, keys)
    return target, clouds, G, p


def surface_cm(model: jp.Cloud, target, G0, p0) -> list[float] | None:
    """Median and 90th percentile of |distance| (cm) of a frame-c model to a box target's surface."""
    if not isinstance(target, Boxes):
        return None
    local = jnp.einsum("ji,nj->ni", G0, model.points - p0[None])
    d = 100 * np.abs(np.asarray(box_distance(local, target)))
    return [float(np.median(d)), float(np.percentile(d, 90))]


def one_case(saved, case: str, index: int) -> dict:
    def get(name):
        return saved[f"{case}/{name}"]

    dt = float(saved["dt"])
    rotations, points, registered, keyframes = get("rotations"), get("points"), get("registered"), get("keyframes")
    frames = np.unique(np.concatenate([[0], keyframes]))
    frames = frames[registered[frames] | (frames == 0)]
    target, clouds, G, p = keyframe_clouds(case, index, frames, dt, rotations.shape[0])
    tracked_R = jnp.asarray(rotations[frames])
    tracked_t = jnp.asarray(points[frames]) - jnp.einsum("fij,j->fi", tracked_R, jnp.asarray(points[0]))
    true_R = jnp.einsum("fij,kj->fik", G, G[0])
    true_t = p - jnp.einsum("fij,j->fi", true_R, p[0])
    eye, zero = jnp.eye(3), jnp.zeros(3)
    tracked = fuse_clouds(clouds.points, clouds.valid, tracked_R, tracked_t, eye, zero, VOXEL)
    exact = fuse_clouds(clouds.points, clouds.valid, true_R, true_t, eye, zero, VOXEL)
    gap = 100 * cKDTree(np.asarray(exact.points)).query(np.asarray(tracked.points))[0]

    dyn = identify_tracked(rotations, points, registered, keyframes, get("measurement_cov"), dt)
    principal = fuse_clouds(clouds.points, clouds.valid, tracked_R, tracked_t, dyn.principal_axes, dyn.centre, VOXEL)
    out = RESULTS / "body_models"
    out.mkdir(exist_ok=True)
    jp.save_cloud(out / f"{case}.ply", principal)
    row = {
        "case": case,
        "frames_fused": int(frames.size),
        "voxels_tracked": int(tracked.points.shape[0]),
        "voxels_true_motion": int(exact.points.shape[0]),
        "to_true_motion_model_cm": [float(np.median(gap)), float(np.percentile(gap, 90))],
        "surface_cm_tracked": surface_cm(tracked, target, G[0], p[0]),
        "surface_cm_true_motion": surface_cm(exact, target, G[0], p[0]),
    }
    print(row, flush=True)
    return row


def markdown(rows: list[dict]) -> str:
    def pair(v):
        return "–" if v is None else f"{v[0]:.2f} / {v[1]:.2f}"

    head = (
        f"Keyframes of the `identify.py` tumbles (σ = 1 cm, {DISTANCE:g} m), fused with 1 cm voxels.\n\n"
        "| case | frames fused | voxels: tracked / true motions | tracked model to the true-motion model, cm: "
        "median / p90 | surface distance, cm, median / p90: tracked | true motions |\n"
        "|---|---|---|---|---|---|\n"
    )
    lines = [
        f"| {r['case']} | {r['frames_fused']} | {r['voxels_tracked']} / {r['voxels_true_motion']} | "
        f"{pair(r['to_true_motion_model_cm'])} | {pair(r['surface_cm_tracked'])} | "
        f"{pair(r['surface_cm_true_motion'])} |"
        for r in rows
    ]
    return head + "\n".join(lines) + "\n"


def main():
    saved = np.load(RESULTS / "identify_tracks.npz")
    rows = [one_case(saved, case, i) for i, case in enumerate(CASES)]
    text = markdown(rows)
    print(text)
    (RESULTS / "body_model.md").write_text(text)
    write_json("body_model.json", {"voxel_m": VOXEL, "rows": rows})


if __name__ == "__main__":
    main()
