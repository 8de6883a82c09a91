"""Two capture cues measured on the capture benchmark's asymmetric pairs, before any of them
enters `jaxpose._capture` (issue 23): a rotation score that needs no translation, and a
translation for a given rotation that needs no start.

`uv run python experiments/capture_cues.py [pairs per bin]` → results/capture_cues.json

On each satellite and fragment pair of `jaxpose.evaluation.capture.make_cases` (both noise
levels, every bin), in the previous cloud's plane frame n:

- **rank of the truth**: among the capture grid's 8216 rotations (`RotationSearch.rotations`
  super-Fibonacci ones and the 24 principal alignments), how many score higher than the best
  one within `NEAR_DEG` of the true rotation, (a) by the capture stage's own grid score, the
  hard objective on the coarse problem with `_capture.overlap_translation`'s translation, and
  (b) by `normal_scores` below, which needs no translation. The capture stage refines its
  `RotationSearch.modes` (16) best distinct candidates, so a rank far past that means the
  truth's basin is not refined.
- **translation error at the true rotation**: `_capture.settled_translation` (what the grid
  uses) against `_capture.correlated_translations` (`_alignment.correlation_translation`:
  one FFT cross-correlation of occupancy grids), centimetres.
- the warm time of the normal scores over the whole grid and of one correlation.

The normal score is here, not in the library: a candidate, measured first. The correlated
translation is the library's (`jaxpose._alignment`), which the capture stage's mode starts use.
"""

from __future__ import annotations

import statistics
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
from _common import write_json
from jaxtyping import Array, Float

import jaxpose as jp
from jaxpose import _capture as capture_stage
from jaxpose._alignment import valid_centroid
from jaxpose._batch import score_batch
from jaxpose._poses import displacement_from_motion
from jaxpose._problem import _build, sized_config
from jaxpose._rotations import angles, rotation_angle, super_fibonacci
from jaxpose.evaluation import capture

NEAR_DEG = 15.0
"""A grid rotation this close to the truth (degrees) lies in the truth's basin."""

NORMAL_POINTS = 256
"""Normals of each view that the normal score compares (spread evenly over the view)."""

NORMAL_KAPPA = 20.0
"""Concentration of the von Mises–Fisher kernel that smooths the normals: two normals 13°
apart still count half (exp(κ(cos 13° − 1)) ≈ 0.6)."""


def normal_scores(
    rotations: Float[Array, "N 3 3"],
    prev_normals: Float[Array, "3 P"],
    prev_weights: Float[Array, " P"],
    prev_points: Float[Array, "3 P"],
    curr_normals: Float[Array, "3 Q"],
    curr_weights: Float[Array, " Q"],
    camera: Float[Array, "3"],
    prev_centroid: Float[Array, "3"],
    curr_centroid: Float[Array, "3"],
) -> Float[Array, " N"]:
    """The normalised correlation (0–1) of the two views' smoothed normal distributions under
    each rotation G^n_ν, counting only the previous normals that still face the camera once
    turned (their points moved by G about the previous centroid onto the current one).

    Normals face the camera and are unit; weights are the points' areas (0 for a point without
    a normal). A rotation that turns the previously seen faces away scores low, one that lays
    them onto the current view's faces scores high, whatever the translation."""
    dtype = prev_normals.dtype
    kernel = lambda a, b: jnp.exp(NORMAL_KAPPA * (a.T @ b - 1.0))  # noqa: E731
    curr_self = curr_weights @ kernel(curr_normals, curr_normals) @ curr_weights
    prev_kernel = kernel(prev_normals, prev_normals)
    offsets = prev_points - prev_centroid[:, None]

    def one(G):
        turned = G @ prev_normals
        moved = G @ offsets + curr_centroid[:, None]
        seen = jnp.sum(turned * (camera[:, None] - moved), axis=0) > 0
        w = jnp.where(seen, prev_weights, 0.0)
        cross = w @ kernel(turned, curr_normals) @ curr_weights
        norm = jnp.sqrt(jnp.maximum((w @ prev_kernel @ w) * curr_self, jnp.finfo(dtype).tiny))
        return cross / norm

    return jax.lax.map(one, rotations, batch_size=64)


@eqx.filter_jit
def cues(prev, curr, config, p_true):
    """Ranks of the truth by both scores, the two translations' errors (metres), and the inputs
    of the timings below."""
    problem = _build(prev, curr, config)
    so3 = config.so3
    surfaces = surfaces_of(problem, so3.points)
    ps, Gs = capture_stage.candidate_displacements(problem, so3.rotations, *surfaces)
    pattern = score_batch(ps, problem.search_problem, so3.objective, chunk=64)
    normal = grid_normal_scores(problem, Gs, *surfaces)
    G_true = jp.rotation(*p_true[:3])
    near = jax.vmap(lambda G: rotation_angle(G, G_true))(Gs) < jnp.radians(NEAR_DEG)

    def rank(scores):
        return jnp.sum(scores > jnp.max(jnp.where(near, scores, -jnp.inf)))

    camera, centroid = capture_stage.camera_in_frame_n(problem), capture_stage.current_centroid(problem)
    overlap = capture_stage.settled_translation(G_true, centroid, *surfaces, camera)
    correlated = capture_stage.correlated_translations(problem, p_true[None])[0, 3:]
    return rank(pattern), rank(normal), jnp.linalg.norm(overlap - p_true[3:]), jnp.linalg.norm(correlated - p_true[3:])


def surfaces_of(problem, size: int):
    """The capture stage's previous and current surfaces, `size` points each."""
    return capture_stage.previous_surface(problem, size), capture_stage.current_surface(problem, size)[0]


def grid_normal_scores(problem, Gs, prev, curr):
    """`normal_scores` of every grid rotation, on `NORMAL_POINTS` of each capture surface."""
    step = max(prev.points.shape[1] // NORMAL_POINTS, 1)
    return normal_scores(
        Gs,
        prev.normals[:, ::step],
        prev.weights[::step],
        prev.points[:, ::step],
        curr.normals[:, ::step],
        curr.weights[::step],
        capture_stage.camera_in_frame_n(problem),
        valid_centroid(problem.fine.points, problem.fine.valid),
        capture_stage.current_centroid(problem),
    )


def warm_ms(fn, *args, repeats: int = 5) -> float:
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times)


def summary(rows, key, within=None):
    values = [r[key] for r in rows]
    out = {"median": statistics.median(values), "max": max(values)}
    if within is not None:
        out[f"at most {within}"] = sum(v <= within for v in values)
    return out


def main(pairs: int = 3) -> None:
    cases, _ = capture.make_cases(pairs)
    config0 = jp.Config.capture()
    rows = []
    for case in cases:
        if case.target not in ("satellite", "fragment"):
            continue
        prev, curr = case.prev.floating(), case.curr.floating()
        config = sized_config(prev, curr, config0)
        frame = jp.plane_frame(prev)
        R, t = (jnp.asarray(x, prev.points.dtype) for x in (case.rotation, case.translation))
        p_true = displacement_from_motion(frame.origin, frame.axes, R, t)
        ranks = cues(prev, curr, config, p_true)
        row = {
            "target": case.target,
            "sigma_cm": case.sigma_cm,
            "bin": f"{case.bin[0]:g}–{case.bin[1]:g}",
            "pair": case.index,
            "motion_deg": round(case.motion_deg, 1),
            "pattern_rank": int(ranks[0]),
            "normal_rank": int(ranks[1]),
            "overlap_translation_error_cm": round(100 * float(ranks[2]), 2),
            "correlation_translation_error_cm": round(100 * float(ranks[3]), 2),
        }
        rows.append(row)
        print(row, flush=True)
    case = next(c for c in cases if c.target == "satellite")
    config = sized_config(case.prev, case.curr, config0)
    problem = eqx.filter_jit(_build)(case.prev.floating(), case.curr.floating(), config)
    surfaces = surfaces_of(problem, config.so3.points)
    Gs = jnp.concatenate([super_fibonacci(config.so3.rotations), capture_stage.principal_alignments(problem)])
    one_mode = jnp.concatenate([angles(Gs[0]), jnp.zeros(3, Gs.dtype)])[None]
    timings = {
        "normal_scores_grid_ms": warm_ms(eqx.filter_jit(grid_normal_scores), problem, Gs, *surfaces),
        "correlation_translation_ms": warm_ms(eqx.filter_jit(capture_stage.correlated_translations), problem, one_mode),
    }
    modes = config0.so3.modes
    report = {
        "command": "uv run python experiments/capture_cues.py " + str(pairs),
        "near_deg": NEAR_DEG,
        "modes": modes,
        "pairs": len(rows),
        "pattern_rank": summary(rows, "pattern_rank", modes),
        "normal_rank": summary(rows, "normal_rank", modes),
        "overlap_translation_error_cm": summary(rows, "overlap_translation_error_cm", 5.0),
        "correlation_translation_error_cm": summary(rows, "correlation_translation_error_cm", 5.0),
        "timings": timings,
        "rows": rows,
    }
    for key in ("pattern_rank", "normal_rank", "overlap_translation_error_cm", "correlation_translation_error_cm"):
        print(key, report[key])
    print(timings)
    write_json("capture_cues.json", report)


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
