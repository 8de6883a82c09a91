"""Capture at any rotation: the global stage over the whole rotation group (`Config.so3`).

The box search of `_search` reaches rotations of tens of degrees. For a first estimate with no
prior, this stage replaces it (DECISIONS.md is silent on capture; the choices are ours):

1. **Candidates** (`candidate_displacements`): a super-Fibonacci grid of rotations over all of
   SO(3) plus the 24 alignments of the two clouds' principal frames. Each gets the translation
   that lines up the surface the two views share (`overlap_translation`), not the centroids'
   shift: after a large turn the camera sees other faces, and the centroids of the two views
   lie tens of centimetres apart on the target.
2. **Scores** of all candidates in batches on the coarse problem (`score_batch`); the best
   `RotationSearch.modes` distinct ones (`distinct_best`) are refined on the coarse problem
   (the configured refine, soft objective).
3. **Hypotheses**: the best `RotationSearch.hypotheses` distinct refined modes, and rest (no
   motion, where a local registration starts: a small turn lies in its basin even where the
   grid's best modes lead elsewhere), are fitted to the surface by two fine-stage passes on
   `RotationSearch.points` current points (a wide inlier gate that pulls the translation in,
   then the configured gate). A mode starts with the translation of the FFT correlation of
   the two clouds' occupancy grids at its rotation (`_alignment.correlation_translation`)
   where that scores higher on the coarse problem than the refine's (`better_translation`):
   on a large target after a large turn the overlap translation can lie tens of centimetres
   off, beyond what the wide gate pulls in.

   **A second look** (`second_look`): the grid's next `RotationSearch.second_look` distinct
   modes take the correlated translation before they are scored again, and the best of them
   are refined and fitted too. Where the overlap translation lies far off, the rotation
   nearest the truth ranks far down the grid and comes back once correlated.
4. **Half-turn twins** (`symmetric_candidates`): the best fitted hypothesis preceded by a half
   turn about each of the face axes (`face_axes`) of both views registered by it
   (`half_turns`, `registered_union`), fitted the same way. The grid's scores favour the
   motion with the most shared surface, so the other motions that a symmetric target's half
   turns make equivalent rarely come out of it.
5. **Ranking** by support: the fit's inlier fraction (the share of the current points it
   explains) times its `consistency` (the share of the surface each view should see of the
   other that it does see). Either alone fails: a motion that maps a small part of the
   target onto itself is perfectly consistent on the little it predicts in view, and a
   motion that lays a large face onto another explains many points while its other faces
   land where the other view sees nothing. A point hidden from the other view by nearer
   surface (its range map, `jaxpose._visibility`) is not expected to be seen: without that,
   a target whose parts hide one another made the truth look less consistent than the
   motions its symmetries make equivalent, which differ in what they hide.
   `Estimate.ambiguous` compares the consistencies: a symmetric target's equivalent motions
   are all consistent, whatever their overlap.

Frames: p and every point here are in the previous cloud's plane frame n (metres, radians);
the camera, at the origin of frame c, is at −G^c_nᵀ O_n in frame n.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from ._alignment import cloud_extent, correlation_target, correlation_translation, valid_centroid
from ._batch import map_batch, score_batch
from ._config import Config
from ._fine import NEIGHBOUR_VOXEL, fine_refine, neighbourhood_planes
from ._neighbours import nearest, spread_subset, voxel_grid, voxel_spacing
from ._poses import preceded_by_turn
from ._problem import Problem
from ._rotations import angles, rotation, rotation_angle, signed_permutations, super_fibonacci
from ._search import local_refine
from ._visibility import RangeMap, hidden, range_map, view_basis

NORMAL_NEIGHBOURS = 12
"""Neighbours of a current point's normal in the overlap and consistency tests."""

SLOTS = 16
"""Points each voxel holds for the neighbour searches of this module (`_neighbours`)."""

OCCLUSION_MARGIN = 0.05
"""A point more than this (metres) behind the nearest surface the other view saw in its
direction is hidden from that view (`jaxpose._visibility.hidden`): several times the range
noise of the benchmarks (σ up to 2 cm head-on) and the depth a surface at grazing incidence
spans across a range-map cell."""

GRAZING_COS = 0.25
"""A point's area weight is r² / max(|cos incidence|, this): the surface a pixel covers grows as
the square of the range and as 1 / cos of the incidence angle, up to this grazing limit."""


class Surface(eqx.Module):
    """Points of one view with their normals turned towards the camera and their area weights
    (frame n, metres; the weight is proportional to the surface a point's pixel covers)."""

    points: Float[Array, "3 S"]
    normals: Float[Array, "3 S"]
    weights: Float[Array, " S"]


class CaptureResult(eqx.Module):
    """The capture stage's outcome (frame n, radians and metres).

    - `params`: `(k, 6)` the hypotheses' p, best first (fitted on `RotationSearch.points`):
      k = `RotationSearch.hypotheses` fitted modes, the `RotationSearch.second_hypotheses` of
      the second look (none where `second_look` is 0), the fit from rest and the three
      half-turn twins.
    - `score`: `(k,)` their support (0–1, module docstring); −1 for a slot that repeats a
      better one.
    - `consistency`: `(k,)` their `consistency` (0–1); −1 for a repeat.
    - `distinct`: `(k,)` whether the slot holds a hypothesis of its own (not within half of
      `RotationSearch.separation_deg` of a better one: under range noise, fits from nearby
      modes land a degree or two apart and are one answer).
    - `grid_best`, `grid_score`: the best candidate of the grid and its coarse objective.
    - `refined`: `(k, 6)` where each hypothesis's fit started: the coarse refine's result
      (with its correlated translation where that scores higher, `better_translation`), the
      second look's refined mode, rest (zeros), or the twin's candidate.
    - `evaluations`: objective evaluations of the grid.
    """

    params: Float[Array, "k 6"]
    score: Float[Array, " k"]
    consistency: Float[Array, " k"]
    distinct: Bool[Array, " k"]
    grid_best: Float[Array, "6"]
    grid_score: Float[Array, ""]
    refined: Float[Array, "k 6"]
    evaluations: Int[Array, ""]


def camera_in_frame_n(problem: Problem) -> Float[Array, "3"]:
    """The camera's centre (the origin of frame c) in frame n, metres."""
    return -problem.frame.axes.T @ problem.frame.origin


def current_centroid(problem: Problem) -> Float[Array, "3"]:
    """The centroid of the valid current points (frame n, metres)."""
    return valid_centroid(problem.curr, problem.curr_valid)


def _towards(normals: Float[Array, "3 S"], points: Float[Array, "3 S"], camera: Float[Array, "3"]):
    """Normals flipped to face `camera`, and the area weight of each point."""
    ray = camera[:, None] - points
    facing = jnp.sum(normals * ray, axis=0)
    normals = normals * jnp.where(facing < 0, -1.0, 1.0)[None]
    r2 = jnp.sum(ray**2, axis=0)
    cos = jnp.abs(facing) / jnp.sqrt(jnp.maximum(r2, jnp.finfo(points.dtype).tiny))
    return normals, r2 / jnp.maximum(cos, GRAZING_COS)


def previous_surface(problem: Problem, size: int) -> Surface:
    """`size` previous points of the fine stage's side with a plane (`FineCloud.valid`), spread
    evenly, with their normals facing the camera."""
    idx, live = spread_subset(problem.fine.valid, size)
    points = problem.fine.points[:, idx]
    normals, weights = _towards(problem.fine.normals[:, idx], points, camera_in_frame_n(problem))
    return Surface(points, normals, jnp.where(live & problem.fine.valid[idx], weights, 0.0))


def current_surface(problem: Problem, size: int):
    """`size` current points spread evenly with normals from their neighbours among all the
    current points, facing the camera; and the voxel grid of all the current points (frame n)."""
    valid = problem.curr_valid
    grid = voxel_grid(problem.curr, valid, NEIGHBOUR_VOXEL * voxel_spacing(problem.curr, valid))
    idx, live = spread_subset(valid, size)
    points = problem.curr[:, idx]
    hood = neighbourhood_planes(grid, problem.curr, points, NORMAL_NEIGHBOURS)
    normals, weights = _towards(hood.normal, points, camera_in_frame_n(problem))
    return Surface(points, normals, jnp.where(live & hood.enough, weights, 0.0)), grid


def _seen_after(G, xyz, surface: Surface, camera) -> Bool[Array, " S"]:
    """Which previous points face the camera once moved by (G, xyz): a = G a + xyz."""
    moved = G @ surface.points + xyz[:, None]
    return (surface.weights > 0) & (jnp.sum((G @ surface.normals) * (camera[:, None] - moved), axis=0) > 0)


def _seen_before(G, xyz, surface: Surface, camera) -> Bool[Array, " S"]:
    """Which current points faced the camera before the motion (G, xyz): b ↦ Gᵀ (b − xyz)."""
    back = G.T @ (surface.points - xyz[:, None])
    return (surface.weights > 0) & (jnp.sum((G.T @ surface.normals) * (camera[:, None] - back), axis=0) > 0)


def overlap_translation(
    G: Float[Array, "3 3"], xyz: Float[Array, "3"], prev: Surface, curr: Surface, camera: Float[Array, "3"]
) -> Float[Array, "3"]:
    """The translation (frame n, metres) that, with rotation G (G^n_ν), maps the area-weighted
    centroid of the previous surface that stays in view onto that of the current surface that
    was in view before. `xyz` is the guess that decides what is in view; `xyz` comes back
    where either part is empty. Self-occlusion is not modelled: a face turned towards the
    camera counts as seen."""
    w_prev = prev.weights * _seen_after(G, xyz, prev, camera)
    w_curr = curr.weights * _seen_before(G, xyz, curr, camera)
    tiny = jnp.finfo(xyz.dtype).tiny
    c_prev = jnp.sum(prev.points * w_prev[None], axis=1) / jnp.maximum(jnp.sum(w_prev), tiny)
    c_curr = jnp.sum(curr.points * w_curr[None], axis=1) / jnp.maximum(jnp.sum(w_curr), tiny)
    usable = (jnp.sum(w_prev) > 0) & (jnp.sum(w_curr) > 0)
    return jnp.where(usable, c_curr - G @ c_prev, xyz)


def settled_translation(
    G: Float[Array, "3 3"], centroid: Float[Array, "3"], prev: Surface, curr: Surface, camera: Float[Array, "3"]
) -> Float[Array, "3"]:
    """`overlap_translation` in two passes: from the current `centroid` (frame n, metres),
    then from the first pass's result, so that what is in view follows the translation."""
    guess = overlap_translation(G, centroid, prev, curr, camera)
    return overlap_translation(G, guess, prev, curr, camera)


def principal_alignments(problem: Problem) -> Float[Array, "24 3 3"]:
    """The rotations G^n_ν that carry the previous cloud's principal axes (the axes of frame n)
    onto the current cloud's, under each of the 24 orders and signs of the axes."""
    valid = problem.curr_valid
    centred = jnp.where(valid[None], problem.curr - current_centroid(problem)[:, None], 0.0)
    _, U = jnp.linalg.eigh(centred @ centred.T)
    U = U.at[:, 2].set(jnp.cross(U[:, 0], U[:, 1]))  # a proper rotation
    return jnp.einsum("ij,sjk->sik", U, signed_permutations().astype(U.dtype))


PRINCIPAL_START_POINTS = 1024
"""Points of each surface that place [`principal_start`][]'s translation."""


def principal_start(problem: Problem) -> Float[Array, "6"]:
    """p (frame n, radians and metres) of the principal alignment nearest the identity (the
    largest trace among [`principal_alignments`][]), with its [`settled_translation`][]:
    the start of `FineStage.from_principal`. The two views'
    inertia frames turn with the target wherever its principal moments are distinct, so over
    the motions between frames this start can lie near the truth where the pattern search
    and rest both miss it. Where two moments nearly tie (a cylinder seen from the side) its
    turn about the third axis is arbitrary."""
    prev = previous_surface(problem, PRINCIPAL_START_POINTS)
    curr, _ = current_surface(problem, PRINCIPAL_START_POINTS)
    Gs = principal_alignments(problem)
    G = Gs[jnp.argmax(jnp.trace(Gs, axis1=1, axis2=2))]
    xyz = settled_translation(G, current_centroid(problem), prev, curr, camera_in_frame_n(problem))
    return jnp.concatenate([angles(G), xyz])


def candidate_displacements(
    problem: Problem, rotations: int, prev: Surface, curr: Surface
) -> tuple[Float[Array, "N 6"], Float[Array, "N 3 3"]]:
    """p of every candidate (frame n): `rotations` super-Fibonacci rotations and the 24
    principal alignments, each with its [`settled_translation`][], and the rotations G^n_ν
    themselves."""
    Gs = jnp.concatenate([super_fibonacci(rotations).astype(problem.d.dtype), principal_alignments(problem)])
    camera = camera_in_frame_n(problem)
    centroid = current_centroid(problem)
    xyz = map_batch(lambda G: settled_translation(G, centroid, prev, curr, camera), Gs, cpu_chunk=256)
    return jnp.concatenate([angles(Gs), xyz], axis=1), Gs


def distinct_best(
    scores: Float[Array, " N"], Gs: Float[Array, "N 3 3"], k: int, separation: float, look: int
) -> tuple[Int[Array, " k"], Bool[Array, " k"]]:
    """Indices of the `k` best-scoring rotations that lie more than `separation` (radians) from
    every better one kept (greedy non-maximum suppression over the `look` best), and which
    slots were filled (a slot left empty repeats the best).

    The suppression runs in k steps, not one per candidate: each step keeps the best candidate
    still open and closes every candidate within `separation` of it. That keeps the same
    rotations as walking the `look` candidates in order and keeping each one apart from all
    kept before it (tested against that walk), with k wide steps in place of `look` narrow
    ones, which on an accelerator are each a few kernel launches."""
    order = jnp.argsort(-scores)[:look]
    ranked = Gs[order]

    def keep_next(slot, state):
        chosen, open_, count = state
        first = jnp.argmax(open_)
        take = open_[first]
        apart = rotation_angle(jnp.broadcast_to(ranked[first], ranked.shape), ranked) > separation
        chosen = jnp.where(take, chosen.at[slot].set(order[first]), chosen)
        return chosen, (open_ & (apart | ~take)).at[first].set(False), count + take

    start = (jnp.full(k, order[0]), jnp.ones(order.shape[0], bool), jnp.asarray(0))
    chosen, _, count = jax.lax.fori_loop(0, k, keep_next, start)
    return chosen, jnp.arange(k) < count


FACE_AXES_STEP_DEG = 5.0
"""Step (degrees) of the turns of the normal tensor's eigenvectors that [`face_axes`][] tries
before its refine: 18 turns over 90° about each eigenvector."""


def face_axes(normals: Float[Array, "3 S"], weights: Float[Array, " S"]) -> Float[Array, "3 3"]:
    """The three orthogonal directions (columns) that the weighted normals cluster about: the
    frame A that maximises Σ w Σ_i (n · a_i)⁴. On a target built of faces these are its face
    normals, whatever share of each face is seen.

    The normal tensor Σ w n nᵀ alone is unreliable there: where two faces are seen with
    similar areas two of its eigenvalues nearly tie, and the eigenvectors of the pair turn
    freely in their plane (on a noisy N5 view of the capture benchmark, 30° away from the
    faces). So the eigenvectors are turned about each of themselves in steps of
    `FACE_AXES_STEP_DEG` over 90°, the best of those 54 frames is kept, and BFGS refines it
    (optimistix, over a rotation vector)."""
    w = weights / jnp.maximum(jnp.sum(weights), jnp.finfo(normals.dtype).tiny)

    def alignment(A):
        return jnp.sum(w[None] * (A.T @ normals) ** 4)

    _, eigen = jnp.linalg.eigh((normals * w[None]) @ normals.T)
    steps = jnp.radians(jnp.arange(0.0, 90.0, FACE_AXES_STEP_DEG, dtype=normals.dtype))
    turns = jnp.concatenate([jnp.outer(steps, jnp.eye(3, dtype=normals.dtype)[i]) for i in range(3)])
    frames = eigen[None] @ jax.vmap(lambda v: jaxlie.SO3.exp(v).as_matrix())(turns)
    start = frames[jnp.argmax(jax.vmap(alignment)(frames))]

    def turned(v):
        return start @ jaxlie.SO3.exp(v).as_matrix()

    solver = optx.BFGS(rtol=1e-6, atol=1e-6)
    found = optx.minimise(
        lambda v, _: -alignment(turned(v)), solver, jnp.zeros(3, normals.dtype), max_steps=64, throw=False
    )
    better = alignment(turned(found.value)) >= alignment(start)
    return jnp.where(better & jnp.all(jnp.isfinite(found.value)), turned(found.value), start)


def registered_union(p: Float[Array, "6"], prev: Surface, curr: Surface) -> Surface:
    """The previous surface together with the current one moved back by the motion p (frame
    n): b ↦ Gᵀ (b − xyz), normals turned with it. After a turn the two views see different
    sides of the target, and together they span more of it than either."""
    G, xyz = rotation(p[0], p[1], p[2]), p[3:]
    back = G.T @ (curr.points - xyz[:, None])
    return Surface(
        jnp.concatenate([prev.points, back], axis=1),
        jnp.concatenate([prev.normals, G.T @ curr.normals], axis=1),
        jnp.concatenate([prev.weights, curr.weights]),
    )


def half_turns(surface: Surface) -> tuple[Float[Array, "3 3 3"], Float[Array, "3"]]:
    """The 180° rotations about the three [`face_axes`][] of `surface` (frame n), and the centre
    they turn about: the middle of the surface's extent along those axes (metres). On a target
    built of faces these are its own axes. Its seen faces span it along every axis across the
    line of sight; along the line of sight a face seen head-on spans nothing, and the middle
    lies on that face. So `symmetric_candidates` takes them from both views
    ([`registered_union`][])."""
    axes = face_axes(surface.normals, surface.weights)
    along = axes.T @ surface.points
    live = (surface.weights > 0)[None]
    middle = (jnp.max(jnp.where(live, along, -jnp.inf), axis=1) + jnp.min(jnp.where(live, along, jnp.inf), axis=1)) / 2
    turns = 2.0 * jnp.einsum("ia,ja->aij", axes, axes) - jnp.eye(3, dtype=axes.dtype)[None]
    return turns, axes @ jnp.where(jnp.isfinite(middle), middle, 0.0)


def symmetric_candidates(p: Float[Array, "6"], prev: Surface, curr: Surface) -> Float[Array, "3 6"]:
    """The motion p (frame n) preceded by each of `half_turns` of the two views registered by p
    ([`registered_union`][]): the candidates for the motions that a target's half-turn
    symmetries would make equivalent to p, to be fitted and scored like any hypothesis. The
    translation comes from the half turn's centre alone: lining up the shared surface
    (`overlap_translation`) would count thin plates, which look alike from both sides, as seen
    after any turn. On the capture benchmark's 30 N5 pairs, starting from the truth, the
    twins started within 3° and 5 cm of the equivalent motion on 86 of 90, against 64 with
    the previous view's normal tensor and extent alone (docs, Capture)."""
    turns, centre = half_turns(registered_union(p, prev, curr))
    return jax.vmap(lambda S: preceded_by_turn(p, S, centre))(turns)


def view_maps(problem: Problem) -> tuple[RangeMap, RangeMap]:
    """The range maps (`jaxpose._visibility`) of the previous view (the fine stage's previous
    points) and of the current view (all current points), frame n, in one tangent plane."""
    camera = camera_in_frame_n(problem)
    basis = view_basis(problem.fine.points, problem.fine.valid, camera)
    return (
        range_map(problem.fine.points, problem.fine.valid, camera, basis),
        range_map(problem.curr, problem.curr_valid, camera, basis),
    )


def expected_in_view(
    problem: Problem, p: Float[Array, "6"], prev: Surface, curr: Surface, views: tuple[RangeMap, RangeMap]
) -> tuple[Float[Array, "3 S"], Bool[Array, " S"], Float[Array, "3 M"], Bool[Array, " M"]]:
    """Under the motion p (frame n): the previous points moved, and which of them the current
    view should see; the current points moved back, and which of them the previous view should
    have seen. A point should be seen when it faces the camera and the other view's range map
    (`views`, [`view_maps`][]) does not put it more than `OCCLUSION_MARGIN` behind nearer
    surface."""
    prev_map, curr_map = views
    G = rotation(p[0], p[1], p[2])
    xyz = p[3:]
    camera = camera_in_frame_n(problem)
    moved = G @ prev.points + xyz[:, None]
    back = G.T @ (curr.points - xyz[:, None])
    seen_prev = _seen_after(G, xyz, prev, camera) & ~hidden(curr_map, moved, OCCLUSION_MARGIN)
    seen_curr = _seen_before(G, xyz, curr, camera) & ~hidden(prev_map, back, OCCLUSION_MARGIN)
    return moved, seen_prev, back, seen_curr


def consistency(
    problem: Problem,
    p: Float[Array, "6"],
    prev: Surface,
    curr: Surface,
    curr_grid,
    gate,
    views: tuple[RangeMap, RangeMap] | None = None,
) -> Float[Array, ""]:
    """How well p explains both clouds (0–1): of the previous points that should be seen after
    the motion and the current points that should have been seen before
    ([`expected_in_view`][]; `views` from [`view_maps`][] where None), the fraction that finds
    a point of the other cloud within `gate` metres (area-weighted). A target's parts that hide
    one another then cost the truth nothing, while a wrong motion still pays for the points it
    puts where the other view saw empty space or farther surface."""
    views = view_maps(problem) if views is None else views
    moved, seen_prev, back, seen_curr = expected_in_view(problem, p, prev, curr, views)
    w_prev = prev.weights * seen_prev
    _, d_prev = nearest(curr_grid, moved, SLOTS)
    w_curr = curr.weights * seen_curr
    _, d_curr = nearest(problem.fine.grid, back, SLOTS)
    hit = jnp.sum(w_prev * (d_prev < gate)) + jnp.sum(w_curr * (d_curr < gate))
    return hit / jnp.maximum(jnp.sum(w_prev) + jnp.sum(w_curr), jnp.finfo(p.dtype).tiny)


def _hypothesis_configs(config: Config) -> tuple[Config, Config]:
    """The two fine-stage passes of a hypothesis: on `RotationSearch.points` current points,
    first with the inlier gate `RotationSearch.wide_inlier` and a loose tolerance, then with
    the configured gate."""
    so3 = config.so3
    narrow = dataclasses.replace(config.fine, points=so3.points, tol=max(config.fine.tol, 1e-3))
    wide = dataclasses.replace(narrow, inlier=so3.wide_inlier, rounds=so3.wide_rounds)
    return dataclasses.replace(config, fine=wide), dataclasses.replace(config, fine=narrow)


def capture_search(problem: Problem, config: Config) -> CaptureResult:
    """The capture stage (module docstring) on a prepared problem. Needs `config.so3` and
    `config.fine`. Pure and jittable."""
    so3 = config.so3
    prev = previous_surface(problem, so3.points)
    curr, curr_grid = current_surface(problem, so3.points)
    ps, Gs = candidate_displacements(problem, so3.rotations, prev, curr)
    scores = score_batch(ps, problem.search_problem, so3.objective, chunk=64)
    separation = math.radians(so3.separation_deg)
    wanted = so3.modes + so3.second_look
    chosen, chosen_filled = distinct_best(scores, Gs, wanted, separation, min(ps.shape[0], 64 * wanted))
    refined = _refined(problem, config, ps[chosen[: so3.modes]])
    top, filled = _best_distinct(problem, refined, so3.hypotheses, separation)
    starts = [better_translation(problem, refined[top])]
    slots = [filled]
    if so3.second_look:
        looked, looked_filled = second_look(problem, config, ps[chosen[so3.modes :]], chosen_filled[so3.modes :])
        starts.append(looked)
        slots.append(looked_filled)
    fit = _hypothesis_fit(problem, config, prev, curr, curr_grid)
    starts = jnp.concatenate([*starts, jnp.zeros((1, 6), refined.dtype)])
    params, score, agree = fit(starts)
    score = jnp.where(jnp.concatenate([*slots, jnp.ones(1, bool)]), score, -1.0)
    twins = symmetric_candidates(params[jnp.argmax(score)], prev, curr)
    twin_params, twin_score, twin_agree = fit(twins)
    params, score, distinct, (agree, starts) = rank_distinct(
        jnp.concatenate([params, twin_params]),
        jnp.concatenate([score, twin_score]),
        math.radians(so3.separation_deg) / 2,
        jnp.concatenate([agree, twin_agree]),
        jnp.concatenate([starts, twins]),
    )
    best = jnp.argmax(scores)
    return CaptureResult(
        params,
        score,
        jnp.where(distinct, agree, -1.0),
        distinct,
        ps[best],
        scores[best],
        starts,
        jnp.asarray(ps.shape[0], jnp.int32),
    )


def _refined(problem: Problem, config: Config, ps: Float[Array, "m 6"]) -> Float[Array, "m 6"]:
    """Each p (frame n) of `ps` refined on the coarse problem (`local_refine`; the refine reads
    only `Config.refine`, which the coarse config shares)."""
    return map_batch(lambda p: local_refine(problem.search_problem, config, p).params, ps)


def _best_distinct(problem: Problem, ps: Float[Array, "m 6"], k: int, separation, live=None) -> tuple:
    """Indices of the `k` distinct best of `ps` (frame n) by the coarse problem's soft
    objective ([`distinct_best`][], `separation` in radians), and which slots were filled.
    `live` (m,): where given, only those rows compete; the others rank behind every live one."""
    scores = score_batch(ps, problem.search_problem, "soft")
    scores = scores if live is None else jnp.where(live, scores, -jnp.inf)
    G = jax.vmap(lambda p: rotation(*p[:3]))(ps)
    return distinct_best(scores, G, k, separation, ps.shape[0])


def second_look(
    problem: Problem, config: Config, ps: Float[Array, "m 6"], filled: Bool[Array, " m"]
) -> tuple[Float[Array, "h 6"], Bool[Array, " h"]]:
    """More hypotheses from the grid's next `RotationSearch.second_look` distinct modes `ps`
    (frame n; `filled` marks the modes the grid had): each takes its correlated translation
    ([`correlated_translations`][]) and is rescored on the coarse problem's hard objective; the
    best `RotationSearch.second_refined` are refined, and the best
    `RotationSearch.second_hypotheses` distinct of those are returned, with which slots were
    filled.

    Why: the grid's overlap translation lies tens of centimetres off after a large turn of a
    large target, so the rotation nearest the truth can rank thousands of places down on the
    grid's scores and then score among the best once correlated (docs, Capture at any
    rotation: where the asymmetric misses come from). Correlating every grid rotation costs
    about 5 ms each; these modes are the ones the grid ranks next."""
    so3 = config.so3
    moved = correlated_translations(problem, ps)
    hard = jnp.where(filled, score_batch(moved, problem.search_problem, "hard"), -jnp.inf)
    _, best = jax.lax.top_k(hard, so3.second_refined)
    refined = _refined(problem, config, moved[best])
    live = filled[best]  # fewer filled modes than `second_refined`: the rest are not picked
    top, top_filled = _best_distinct(problem, refined, so3.second_hypotheses, math.radians(so3.separation_deg), live)
    return refined[top], top_filled & live[top]


def correlated_translations(problem: Problem, ps: Float[Array, "m 6"]) -> Float[Array, "m 6"]:
    """Each p (frame n) of `ps` with its translation replaced by the one that overlaps the fine
    stage's previous points, turned by p's rotation, most with the current points
    (`_alignment.correlation_translation`, over grids spanning twice the clouds' extent; the
    current side's grid is built once for all of them)."""
    fine = problem.fine
    extent = jnp.maximum(cloud_extent(fine.points, fine.valid), cloud_extent(problem.curr, problem.curr_valid))
    target = correlation_target(problem.curr, problem.curr_valid, extent)

    def one(p):
        xyz = correlation_translation(rotation(p[0], p[1], p[2]), fine.points, fine.valid, target)
        return p.at[3:].set(xyz.astype(p.dtype))

    return map_batch(one, ps)


def better_translation(problem: Problem, ps: Float[Array, "m 6"]) -> Float[Array, "m 6"]:
    """Each p (frame n) of `ps`, or the same rotation with its correlated translation
    ([`correlated_translations`][]) where that scores higher on the coarse problem's hard
    objective."""
    moved = correlated_translations(problem, ps)
    kept, better = (score_batch(x, problem.search_problem, "hard") for x in (ps, moved))
    return jnp.where((better > kept)[:, None], moved, ps)


def _hypothesis_fit(problem: Problem, config: Config, prev: Surface, curr: Surface, curr_grid):
    """The fit of a batch of hypotheses `(m, 6)` (frame n): the two surface fits of
    `_hypothesis_configs`, then each result's support (the fit's inlier fraction times its
    `consistency`; −1 where the fit is not finite) and its consistency."""
    wide, narrow = _hypothesis_configs(config)
    gate = jnp.asarray(config.fine.inlier, problem.d.dtype)
    views = view_maps(problem)

    def one(p):
        fitted = fine_refine(problem, narrow, fine_refine(problem, wide, p).params)
        agree = consistency(problem, fitted.params, prev, curr, curr_grid, gate, views)
        usable = jnp.all(jnp.isfinite(fitted.params))
        return fitted.params, jnp.where(usable, fitted.inliers * agree, -1.0), agree

    return lambda ps: map_batch(one, ps)


def rank_distinct(params: Float[Array, "k 6"], score: Float[Array, " k"], separation, *carried) -> tuple:
    """Hypotheses sorted by `score`, best first, each within `separation` (radians) of a better
    one marked as a repeat (score −1, not distinct) and moved behind the distinct ones; the
    arrays `carried` (leading axis k) follow the same order. Returns (params, score, distinct,
    carried)."""
    order = jnp.argsort(-score)
    params, score = params[order], score[order]
    carried = tuple(c[order] for c in carried)
    G = jax.vmap(lambda p: rotation(*p[:3]))(params)
    k = score.shape[0]
    apart = (
        rotation_angle(jnp.broadcast_to(G[:, None], (k, k, 3, 3)), jnp.broadcast_to(G[None], (k, k, 3, 3))) > separation
    )
    close_to_better = jnp.any(~apart & jnp.tri(k, k=-1, dtype=bool), axis=1)
    distinct = ~close_to_better & (score >= 0)
    score = jnp.where(distinct, score, -1.0)
    order = jnp.argsort(-score)
    return params[order], score[order], distinct[order], tuple(c[order] for c in carried)


__all__ = ["CaptureResult", "capture_search", "consistency", "distinct_best", "overlap_translation"]
