"""`estimate`: the displacement between two clouds, end to end, with a status.

Problem → global search (CMA-ES) → local refine (soft objective; not in `Config()`) → fine
stage (point-to-plane least squares, `_fine`) → hard score reported; the result is a `Status`
item.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ._batch import score_batch
from ._capture import capture_search, principal_start, view_maps
from ._checks import is_concrete
from ._cloud import Cloud
from ._config import Config
from ._fine import (
    FineResult,
    FitMatches,
    RotationHold,
    SlideHold,
    exact_surface,
    face_holds,
    fine_refine,
    fit_matches,
    fits_two_way,
    without_range_noise,
)
from ._frame import PlaneFrame
from ._objective import hard_score, soft_score
from ._poses import motion_from_displacement, preceded_by_turn
from ._problem import Problem, _build, check_range, raise_for_codes, run_growing, sized_config
from ._programs import BoundedJit
from ._rotations import rotation, rotation_angle
from ._search import GlobalResult, LocalResult, box_scale, local_refine, restarted_search
from ._tree import tree_select
from ._uncertainty import motion_uncertainty, rotation_std
from ._visibility import RangeMap, in_front


class Status(eqx.Enumeration):
    """Why an estimate is or is not a success: the `result` of an [`Estimate`][jaxpose.Estimate].
    `Status[est.result]` gives the message (concrete results only); the item's integer code is
    `Estimate.status`."""

    success = "success"
    not_converged = "the local refine or the fine stage did not converge"
    low_score = "the best hard score is below Thresholds.min_score: the patterns do not match"
    degenerate = "the problem is unusable (see Problem.status: frame, capacities, too few points)"
    non_finite = "a non-finite value appeared"
    at_box_edge = (
        "the global search ended at the edge of its box (after GlobalSearch.recentre re-centred searches): "
        "the motion may lie outside it; widen the box (Config.wide()) or give a prior"
    )
    ambiguous = (
        "two surface fits (from the pattern search's result, from rest, or turned about a near-symmetry "
        "axis) explain the current cloud equally well, or contradict what the two views saw equally little, "
        "or one explains more of the current cloud while the other contradicts the views less, "
        "and they differ by more than Thresholds.ambiguous_deg: "
        "the views do not fix the motion (e.g. a turn about a near-symmetry axis); Estimate.alternative "
        "holds the other fit"
    )
    uncertain = (
        "the fit's rotation uncertainty (the largest standard deviation of Estimate.covariance, combined with half "
        "Estimate.spread, the angle to another equally good fit) exceeds Thresholds.max_rotation_std_deg: the "
        "clouds do not pin the motion down to the 1° a success promises; or the matched faces barely hold a turn "
        "(Estimate.hold.lever below Thresholds.min_rotation_lever; Estimate.hold.axis is its axis, camera frame) "
        "or a translation (Estimate.slide.grip below Thresholds.min_translation_grip; Estimate.slide.direction "
        "is its direction, camera frame)"
    )


_NAMES = tuple(Status._name_to_item)
SUCCESS, NOT_CONVERGED, LOW_SCORE, DEGENERATE, NON_FINITE, AT_BOX_EDGE, AMBIGUOUS, UNCERTAIN = (
    _NAMES.index(name)
    for name in (
        "success",
        "not_converged",
        "low_score",
        "degenerate",
        "non_finite",
        "at_box_edge",
        "ambiguous",
        "uncertain",
    )
)
"""The integer codes of `Status`'s items (`Estimate.status`), for code that compares arrays."""
STATUS_TEXT = dict(enumerate(Status._index_to_message))
"""Code → message of each `Status` item."""
STATUS_NAME = {code: name.replace("_", " ") for code, name in enumerate(_NAMES)}
"""Code → short name of each `Status` item, for tables."""


class Hypotheses(eqx.Module):
    """The distinct motions that explain a pair, best first (`Estimate.hypotheses`).

    - `params`: `(k, 6)` p in frame n (radians and metres).
    - `rotation`, `translation`: `(k, 3, 3)` and `(k, 3)`, the motions in the camera frame,
      x ↦ R x + t, like `Estimate.rotation` and `Estimate.translation`.
    - `score`: `(k,)` how well each explains the clouds, 0–1, higher is better: with the
      capture stage (`Config.so3`) its support, the share of the current points its surface
      fit explains times the share of the surface each view should see of the other (facing
      the camera and not hidden behind nearer surface) that it does see
      (`jaxpose._capture.consistency`); otherwise the fine stage's inlier
      fraction (0 for the estimate when the fine stage's result was dropped for its start's,
      1 for the single slot of a config without a fine stage). −1 in a slot without a
      hypothesis of its own.
    - `distinct`: `(k,)` whether the slot holds one (False: a repeat of a better one, or none).

    Slot 0 is the estimate itself.
    """

    params: Float[Array, "*batch k 6"]
    rotation: Float[Array, "*batch k 3 3"]
    translation: Float[Array, "*batch k 3"]
    score: Float[Array, "*batch k"]
    distinct: Bool[Array, "*batch k"]


def hypotheses_of(frame: PlaneFrame, params, score, distinct) -> Hypotheses:
    """`Hypotheses` from p (frame n) of each, with their camera-frame motions."""
    R, t = jax.vmap(lambda p: motion_from_displacement(frame.origin, frame.axes, p))(params)
    return Hypotheses(params, R, t, score, distinct)


class Estimate(eqx.Module):
    """Result of [`estimate`][jaxpose.estimate].

    **Fields:**

    - `params`: p = (θ, φ, ψ, x, y, z), radians and metres, frame ν relative to frame n.
    - `rotation`, `translation`: the target motion in the camera frame, x ↦ R x + t, so
      estimates can be chained.
    - `frame`: the plane frame n of the previous cloud.
    - `hard`, `soft`: the objectives at `params`.
    - `result`: a [`Status`][jaxpose.Status] item; `Status[est.result]` is its message.
    - `search`: the global stage's `GlobalResult` (best p and score before the refine, the
      best score of each CMA-ES generation of the first search of the restart that gave the
      result, evaluations, whether it ended at the box edge, re-centrings and restarts).
    - `refine`: the local stage's `LocalResult` (its p, soft score, convergence and steps;
      without a refine, `Config.refine` None, the search's best, its soft score, converged and
      0 steps).
    - `fine`: the fine stage's `FineResult` (p, convergence, Gauss–Newton steps over
      all rounds, inlier fraction and inlier RMS point-to-plane residual in metres), or None
      when `Config.fine` is None.
    - `fine_kept`: whether `params` is the fine stage's result (False: no fine stage, or its
      hard score fell more than `FineStage.guard` below its start's, the refine's result or
      the search's best, which then stands).
    - `ambiguous`: two surface fits (from the refine's result or the search's best, from rest,
      `FineStage.from_rest`, or turned about a near-symmetry axis) are left undecided by the
      views (equally good, or ranked oppositely by the inlier fraction and the free-space
      conflict: `jaxpose._estimate.equally_good_and_apart`) and their rotations differ by
      more than `Thresholds.ambiguous_deg`; with the capture stage, a distinct hypothesis
      is as consistent with both views as the best, within `RotationSearch.tie`. The result
      is then `Status.ambiguous`.
    - `alternative`: p (frame n) of the fit that was not chosen (equal to `params` without
      `FineStage.from_rest` or a fine stage).
    - `covariance`: `(6, 6)` predicted covariance of the motion in the camera frame: the
      rotation as a left rotation vector R R̂ᵀ in radians, then the translation in metres
      (`jaxpose._uncertainty.motion_covariance`: the fine stage's least squares σ̂² (JᵀJ)⁻¹,
      times a factor that grows with σ̂, `FineStage.covariance_scale` ·
      (1 + σ̂ / `FineStage.covariance_noise`), calibrated on varied noisy pairs), or None
      without a fine stage. Its largest rotation standard deviation, combined with half the
      `spread`, above `Thresholds.max_rotation_std_deg` makes the result `Status.uncertain`.
    - `residual_scale`: σ̂, metres: the scale of the fine fit's point-to-plane residuals that
      `covariance` was computed with (at least `jaxpose._fine.SIGMA_FLOOR`); it measures the
      range noise of the two views. None without a fine stage.
    - `spread`: the largest rotation angle (radians) between the estimate and another fit of
      the fine stage, from another start, that explains the current cloud as well (inlier
      fractions within `FINE_TIE`; `jaxpose._estimate.fit_spread`): two minima of the fine
      objective that the data do not tell apart. 0 where there is none, where the fine
      stage's result was not kept, and with the capture stage.
    - `hold`: how firmly the matched faces hold the rotation
      ([`RotationHold`][jaxpose.RotationHold]: the `lever` in metres of the turn they
      hold least, and that turn's `axis` in the camera frame), or None without a fine stage.
      A lever below `Thresholds.min_rotation_lever` makes the result `Status.uncertain`: the
      views do not fix the turn about `axis` (a single flat face seen head-on, about its
      normal).
    - `slide`: how firmly the matched faces hold the translation
      ([`SlideHold`][jaxpose.SlideHold]: the `grip`, dimensionless, of the translation they
      hold least, and its `direction` in the camera frame), or None without a fine stage. A
      grip below `Thresholds.min_translation_grip` makes the result `Status.uncertain`: only
      the view's outline fixes the translation along `direction` (two flat faces, along
      their common edge).
    - `hypotheses`: the distinct motions found, best first ([`Hypotheses`][jaxpose.Hypotheses]):
      with the capture stage (`Config.so3`) its fitted modes, the second look's, the fit
      from rest and the three half-turn twins (`jaxpose._capture.CaptureResult`); otherwise
      the chosen fit and the alternative (or the estimate alone without a fine stage).
    """

    params: Float[Array, "6"]
    rotation: Float[Array, "3 3"]
    translation: Float[Array, "3"]
    frame: PlaneFrame
    hard: Float[Array, ""]
    soft: Float[Array, ""]
    result: Status
    search: GlobalResult
    refine: LocalResult
    fine: FineResult | None
    fine_kept: Bool[Array, ""]
    ambiguous: Bool[Array, ""]
    alternative: Float[Array, "6"]
    hypotheses: Hypotheses
    covariance: Float[Array, "6 6"] | None
    spread: Float[Array, ""]
    hold: RotationHold | None = None
    slide: SlideHold | None = None
    residual_scale: Float[Array, ""] | None = None

    @property
    def status(self) -> Int[Array, "*batch"]:
        """The integer code of `result` (`SUCCESS` = 0; `STATUS_TEXT` / `STATUS_NAME`)."""
        return jnp.asarray(self.result._value, jnp.int32)

    @property
    def success(self) -> Bool[Array, "*batch"]:
        return self.result == Status.success

    @property
    def stats(self) -> dict[str, Int[Array, ""]]:
        """The work done: objective evaluations of the global stage, refine steps, fine-stage
        steps (all rounds; 0 without one), re-centred searches and restarts."""
        return {
            "evaluations": self.search.evaluations,
            "refine_steps": self.refine.steps,
            "fine_steps": jnp.asarray(0, jnp.int32) if self.fine is None else self.fine.steps,
            "recentred": self.search.recentred,
            "restarts": self.search.restarts,
        }


FINE_TIE = 0.01
"""Inlier fractions closer than this count as equal when two fine-stage results are compared."""

TURN_TIE = 0.02
"""Inlier fractions closer than this make a fit turned about a near-symmetry axis a rival that
the views do not rule out (`Status.ambiguous`), where the best fit's residuals show range
noise ([`turn_tie`][]). Wider than `FINE_TIE`: on 18 of the realistic benchmark's noisy upper
stages where the fine stage found both a fit within 1° of the truth and one farther off, the
right fit explained up to 0.0105 fewer current points than the wrong one (4 pairs) or
0.003–0.015 more (4 pairs): differences this small are noise (docs, Findings: turns about a
near-symmetry axis; `experiments/fine_runs.py`)."""


def turn_tie(best: FineResult) -> Float[Array, ""]:
    """The inlier tie for the turned fits against `best`: `TURN_TIE` where its residuals show
    range noise, `FINE_TIE` where they do not (`_fine.without_range_noise`, the views that are
    polished). Without noise to move points across the inlier gate, a difference of 1.5 % is
    the shape's: on two noise-free upper stages a turn 15° off explained 1.5–1.6 % fewer
    points than the truth's fit, with the same RMS."""
    return jnp.where(without_range_noise(best), FINE_TIE, TURN_TIE)


FREE_SPACE_MARGIN = 0.02
"""A point counts against a fit when the fit puts it more than this (metres) in front of the
nearest surface the other view saw in its direction ([`free_space_conflict`][]): below the
height of the small parts (fittings, tunnels, booms, 4–15 cm) whose misplacement gives a
wrong turn away. Chosen, not tuned: on four draws of the realistic benchmark a 4 cm margin
found the same number of pairs at every noise level (docs, Findings: free space decides
between fits far apart)."""

CONFLICT_TIE = 0.002
"""Conflict shares ([`free_space_conflict`][]) closer than this leave two fits far apart
undecided by the views: the estimate is then `Status.ambiguous` ([`equally_good_and_apart`][])."""


def free_space_conflict(problem: Problem, p: Float[Array, "6"], views: tuple[RangeMap, RangeMap]) -> Float[Array, ""]:
    """The share (0–1) of both clouds' points that the displacement p (frame n) puts where the
    other view saw through them: the previous points (`problem.fine.points`) moved by p that the
    current view's range map has more than `FREE_SPACE_MARGIN` in front of its nearest surface
    or in an empty cell, and the current points (`problem.curr`) moved back by p that the
    previous view's map has so (`jaxpose._visibility.in_front`). `views`: the previous and the
    current range maps (`jaxpose._capture.view_maps`).

    A right fit leaves only edges and noise there. A wrong one that lays most of a surface onto
    itself, such as a turn about a near-symmetry axis, or about a faceted cylinder's facet,
    still puts its small parts (fittings, tunnels, booms) in front of surface the other view
    saw, or beside the silhouette. The inlier fraction cannot see this: the wrong turn may
    even explain more of the current cloud, as it lines up more of the two views' visible
    arcs (docs, Findings: free space decides between fits far apart)."""
    prev_map, curr_map = views
    G = rotation(p[0], p[1], p[2])
    xyz = p[3:]
    fine = problem.fine
    moved = G @ fine.points + xyz[:, None]
    back = G.T @ (problem.curr - xyz[:, None])
    forward = fine.valid & in_front(curr_map, moved, FREE_SPACE_MARGIN)
    backward = problem.curr_valid & in_front(prev_map, back, FREE_SPACE_MARGIN)
    count = jnp.sum(fine.valid) + jnp.sum(problem.curr_valid)
    return (jnp.sum(forward) + jnp.sum(backward)) / jnp.maximum(count, 1)


def judged(a: FineResult, b: FineResult) -> Bool[Array, ""]:
    """Whether both fits are live (some inliers) and have their conflicts judged (finite
    [`free_space_conflict`][]): only then can the views decide between them."""
    return (a.inliers > 0) & (b.inliers > 0) & jnp.isfinite(a.conflict) & jnp.isfinite(b.conflict)


def prefers(a: FineResult, b: FineResult, config: Config | None = None) -> Bool[Array, ""]:
    """Whether b explains the two clouds better than a.

    With `config`, two live fits far apart (more than `Thresholds.ambiguous_deg` apart, with
    judged conflicts: [`judged`][]) are two different motions, and the one that
    contradicts the views less wins: the smaller [`free_space_conflict`][], by more than
    `CONFLICT_TIE` (where the inlier fraction ranks them the other way, the estimate is
    ambiguous: [`disagree`][]). Otherwise (conflicts within the tie, which also makes the
    estimate ambiguous; two fits of nearly the same motion; or without `config`): the larger inlier
    fraction, or, within `FINE_TIE`, the smaller weighted RMS residual. A face seen head-on
    is why the tie falls back: fits turned 0.6° and 1.4° in its plane both put nothing where
    the other view saw through (`tests/test_realistic.py`, one face seen head-on)."""
    by_cloud = (b.inliers > a.inliers + FINE_TIE) | ((b.inliers >= a.inliers - FINE_TIE) & (b.rms < a.rms))
    if config is None:
        return by_cloud
    decided = judged(a, b) & apart(a, b, config) & (jnp.abs(b.conflict - a.conflict) > CONFLICT_TIE)
    return jnp.where(decided, b.conflict < a.conflict, by_cloud)


def better_fine(a, b, config: Config | None = None):
    """The fine-stage result that explains the clouds better ([`prefers`][])."""
    return tree_select(prefers(a, b, config), b, a)


def rotation_between(p: Float[Array, "6"], q: Float[Array, "6"]) -> Float[Array, ""]:
    """The angle (radians) between the rotations of two displacements p, q (frame n)."""
    return rotation_angle(rotation(*p[:3]), rotation(*q[:3]))


def rotations_apart(p: Float[Array, "6"], q: Float[Array, "6"], config: Config) -> Bool[Array, ""]:
    """Whether the rotations of two displacements p, q (frame n) differ by more than
    `Thresholds.ambiguous_deg`."""
    return rotation_between(p, q) > jnp.radians(config.thresholds.ambiguous_deg)


def apart(a: FineResult, b: FineResult, config: Config) -> Bool[Array, ""]:
    """Whether the rotations of two fine-stage results differ by more than
    `Thresholds.ambiguous_deg` ([`rotations_apart`][])."""
    return rotations_apart(a.params, b.params, config)


def equally_good_and_apart(
    a: FineResult, b: FineResult, config: Config, tie: float | Float[Array, ""] = FINE_TIE
) -> Bool[Array, ""]:
    """Whether two fine-stage results whose rotations differ by more than
    `Thresholds.ambiguous_deg` are left undecided by the views: inlier fractions within `tie`,
    or, where both conflicts are judged, conflict shares within `CONFLICT_TIE`
    ([`free_space_conflict`][]), or the two measures ranking them oppositely
    ([`disagree`][]). The estimate is then `Status.ambiguous`."""
    close_inliers = jnp.abs(a.inliers - b.inliers) <= tie
    close_conflicts = judged(a, b) & (jnp.abs(a.conflict - b.conflict) <= CONFLICT_TIE)
    return (close_inliers | close_conflicts | disagree(a, b)) & apart(a, b, config)


def disagree(a: FineResult, b: FineResult) -> Bool[Array, ""]:
    """Whether the free-space conflict and the inlier fraction rank two judged fits
    ([`judged`][]) oppositely, each beyond its tie: one puts fewer points where the other view
    saw through (conflict shares more than `CONFLICT_TIE` apart) while the other explains
    more of the current cloud (inlier fractions more than [`turn_tie`][] of `a` apart: the
    band within which range noise moves them).

    [`prefers`][] follows the conflict between fits far apart, and the conflict is usually
    right where they disagree: the inlier fraction measures overlap, and a turn about a
    near-symmetry axis can line up more of two views than the truth does. Not always: on a
    noise-free upper stage (held-out draw, seed 5, #4) the truth's fit explained 0.017 more of
    the current cloud and the fit 15° away about the long axis had a conflict 0.007 smaller:
    by the conflict alone that turn is a success 15° off (docs, Findings: when the two
    measures disagree). Where they disagree, the views do not settle the choice."""
    tie = turn_tie(a)
    fewer_conflicts = b.conflict < a.conflict - CONFLICT_TIE
    more_conflicts = b.conflict > a.conflict + CONFLICT_TIE
    more_inliers = b.inliers > a.inliers + tie
    fewer_inliers = b.inliers < a.inliers - tie
    return judged(a, b) & ((fewer_conflicts & fewer_inliers) | (more_conflicts & more_inliers))


def symmetry_turns(frame: PlaneFrame, config: Config) -> Float[Array, "2 3"]:
    """The two turns, ±`FineStage.turn_deg` about the previous cloud's near-symmetry axis, as
    rotation vectors in frame ν (radians); zero when the view is not nearly symmetric.

    The frame's principal moments come in descending order, one per axis of frame n. When the
    two largest are within `FineStage.symmetry_ratio` of each other the cloud is elongated
    (a cylinder seen from the side) and the axis of the smallest moment, axis 3, is the one it
    nearly turns about; when the two smallest are, it is flat (a disk) and the axis is axis 1.
    The moved frame ν carries the previous body's axes, so the same axis serves there."""
    moments, ratio = frame.inertia, config.fine.symmetry_ratio
    elongated = moments[1] >= ratio * moments[0]
    flat = moments[2] >= ratio * moments[1]
    axis = jnp.where(elongated, jnp.eye(3, dtype=moments.dtype)[2], jnp.eye(3, dtype=moments.dtype)[0])
    angle = jnp.where(elongated | flat, jnp.radians(config.fine.turn_deg), 0.0).astype(moments.dtype)
    return jnp.stack([angle * axis, -angle * axis])


SYMMETRY_CENTRE_PRIOR = 1e-4
"""Weight, relative to the normals' own, that pulls [`symmetry_centre`][] towards the frame's
origin: it fixes the directions the normals leave free (a single flat face) and nothing else."""


def symmetry_centre(
    points: Float[Array, "3 K"], normals: Float[Array, "3 K"], valid: Bool[Array, " K"], turn: Float[Array, "3"]
) -> Float[Array, "3"]:
    """The point (frame n, metres) on the near-symmetry axis of [`symmetry_turns`][] that the
    turns go about: where the previous surface's normal lines, seen along the axis, meet.

    For a cylinder seen from the side the normals point away from its axis, and the visible
    points' centroid, the frame's origin, lies towards the camera, off the axis by about half
    the radius: a turn about the origin then slides the surface sideways, out of the fine
    stage's reach (a spent upper stage's 14° turn ended back at the wrong fit). The centre
    is the least-squares point closest to every planar point's normal line, projected across
    the axis and weighted by the squared sine of the normal's angle to it, with a weak pull
    (`SYMMETRY_CENTRE_PRIOR`) to the origin. It lies on the axis through the origin where the
    normals fix nothing (a disk's face, a single flat side), and never farther from the origin
    than the farthest previous point. Zero without a turn.

    `points`, `normals`, `valid`: the previous points, their unit normals and which have one
    (`FineCloud.points`, `.normals`, `.valid`); `turn`: a rotation vector about the axis."""
    dtype = points.dtype
    axis = turn / jnp.maximum(jnp.linalg.norm(turn), jnp.finfo(dtype).tiny)
    across = jnp.eye(3, dtype=dtype) - jnp.outer(axis, axis)
    m = across @ normals  # (3, K): the normals' parts across the axis
    weight = jnp.where(valid, jnp.sum(m * m, axis=0), 0.0)
    u = m / jnp.maximum(jnp.linalg.norm(m, axis=0, keepdims=True), jnp.finfo(dtype).tiny)
    # Σ w (P − u uᵀ): the squared distance to each normal line, across the axis.
    normal_space = jnp.sum(weight) * across - jnp.einsum("k,ik,jk->ij", weight, u, u)
    x = across @ points
    rhs = jnp.sum(weight[None] * x, axis=1) - jnp.einsum("k,ik,k->i", weight, u, jnp.sum(u * x, axis=0))
    prior = SYMMETRY_CENTRE_PRIOR * jnp.maximum(jnp.sum(weight), 1.0)
    centre = jnp.linalg.solve(normal_space + prior * across + jnp.outer(axis, axis), rhs)
    reach = jnp.max(jnp.where(valid, jnp.linalg.norm(points, axis=0), 0.0))
    size = jnp.linalg.norm(centre)
    centre = jnp.where(size > reach, centre * reach / jnp.maximum(size, jnp.finfo(dtype).tiny), centre)
    turning = jnp.any(turn != 0) & jnp.all(jnp.isfinite(centre))
    return jnp.where(turning, centre, jnp.zeros_like(centre))


def turned(p: Float[Array, "6"], turn: Float[Array, "3"], centre: Float[Array, "3"] | None = None) -> Float[Array, "6"]:
    """The displacement p (frame n) with the body turned further by the rotation vector `turn`
    (radians, about an axis of frame ν) about its point `centre` (frame n, metres; default the
    origin) before it moves: G' = G S and x' = x + G (c − S c), S = exp(turn). A body nearly
    symmetric about an axis through c looks almost the same after such a turn
    ([`jaxpose._poses.preceded_by_turn`][] with S = exp(turn))."""
    centre = jnp.zeros(3, p.dtype) if centre is None else centre
    return preceded_by_turn(p, jaxlie.SO3.exp(turn).as_matrix(), centre)


def polished(fine: FineResult, exact: FineResult) -> FineResult:
    """`fine`, or its polish `exact` (the same fit run again from `fine.params` against planes
    through the previous points, `_fine.exact_surface`) when `fine`'s residuals show no range
    noise (`_fine.without_range_noise`): there the centroid anchor only adds its curvature
    bias, and the point anchor is exact. On the realistic subset's noise-free pairs the median
    centroid error went from 0.09 to 0.01 cm (docs, Findings: the fine stage's anchor on the
    realistic benchmark). The polish replaces `fine` only when it converged and explains the
    cloud at least as well (`better_fine`)."""
    exact = tree_select(exact.converged | ~fine.converged, exact, fine)
    return tree_select(without_range_noise(fine), better_fine(fine, exact), fine)


def finishes_two_way(config: Config) -> bool:
    """Whether the fine stage's fits run one-way and a last pass adds the two-way residuals
    (`FineStage.symmetric` "finish" on the whole surface): see [`fine_passes`][]."""
    return config.fine.symmetric == "finish" and config.fine.two_way


def has_last_pass(config: Config) -> bool:
    """Whether [`fine_passes`][] ends with a last pass after the fits: the noise-free polish
    (an anchor other than "point") or the two-way finish ([`finishes_two_way`][])."""
    return config.fine.anchor != "point" or finishes_two_way(config)


def finished(fine: FineResult, runs: FineResult, fits: int, config: Config) -> FineResult:
    """The chosen fit `fine` after the last pass of [`fine_passes`][] (run `fits` of `runs`),
    which started from the best of the first `fits` runs ([`best_run`][]): where `fine` shows
    no range noise, its polish ([`polished`][]); else, where the last pass was the two-way
    finish (a live run) and started from `fine`, that finish when it converged; else
    `fine`."""
    last = _take(runs, fits)
    polish = polished(fine, last) if config.fine.anchor != "point" else fine
    if not finishes_two_way(config):
        return polish
    same_start = jnp.all(best_run(runs, fits, config).params == fine.params)
    take = same_start & (last.inliers > 0) & last.converged & jnp.all(jnp.isfinite(last.params))
    two_way = tree_select(take, last, fine)
    return tree_select(without_range_noise(fine), polish, two_way)


def contest(best: FineResult, other: FineResult, ambiguous, challenger: FineResult, config: Config):
    """A turned fit (the challenger) against the best so far, the runner-up `other` and whether
    the estimate is ambiguous. The challenger becomes the best when preferred ([`prefers`][]),
    and the best it displaces becomes the runner-up if the two lie apart. A challenger that
    loses becomes the runner-up when it lies apart from the best and the runner-up does not,
    or is less preferred. A challenger that lies apart and is within [`turn_tie`][] of the
    best's inlier fraction, or within `CONFLICT_TIE` of its conflict share, or that the two
    measures rank against the best oppositely ([`disagree`][]), makes the estimate ambiguous
    (`equally_good_and_apart`). An inactive run (no inliers) changes nothing."""
    live = challenger.inliers > 0
    far = apart(best, challenger, config)
    wins = live & prefers(best, challenger, config)
    rival = live & ~wins & far & (~apart(best, other, config) | prefers(other, challenger, config))
    tied = live & equally_good_and_apart(best, challenger, config, turn_tie(best))
    demoted = wins & far
    runner_up = tree_select(demoted, best, tree_select(rival, challenger, other))
    return tree_select(wins, challenger, best), runner_up, ambiguous | tied


def _take(tree, i: int | Int[Array, ""]):
    return jax.tree.map(lambda x: x[i], tree)


def best_run(runs: FineResult, count: int, config: Config | None = None) -> FineResult:
    """The best (`better_fine`, with `config`) of the first `count` runs of a stacked
    `FineResult`."""
    best = _take(runs, 0)
    for i in range(1, count):
        best = better_fine(best, _take(runs, i), config)
    return best


def fit_spread(chosen: FineResult, runs: FineResult, count: int) -> Float[Array, ""]:
    """The largest rotation angle (radians) between the chosen fit and any of the first `count`
    runs of the fine stage that explains the current cloud as well: live (some inliers) and
    with an inlier fraction within `FINE_TIE` of the chosen fit's, the tie within which
    [`prefers`][] decides by the RMS residual alone. 0 where no other fit ties.

    Two such fits are two minima of the fine objective that the data do not tell apart, and
    the estimate is one of them: a two-point spread of this angle has a standard deviation
    of half of it, which the status adds to the least-squares one ([`is_uncertain`][]). The
    least-squares covariance measures the curvature of one minimum only: on the realistic
    benchmark's satellite at σ 2 cm (#6) the fits from the refine's result and from rest
    ended 3.1° and 3.85° from the truth, 0.76° apart, and the estimate's covariance predicted
    0.098°."""

    inliers = runs.inliers[:count]
    tied = (inliers > 0) & (jnp.abs(inliers - chosen.inliers) <= FINE_TIE)
    angles = jax.vmap(lambda q: rotation_between(chosen.params, q))(runs.params[:count])
    return jnp.max(jnp.where(tied & jnp.isfinite(angles), angles, 0.0))


def fine_passes(
    problem: Problem, config: Config, starts: Float[Array, "k 6"], turns: Float[Array, "r 3"] | None = None
) -> FineResult:
    """The fine stage's runs, stacked `(k + r + 1,)` (or `(k + r,)` where the config has no
    last pass, [`has_last_pass`][]): run i < k from `starts[i]` (frame n); then run k + j from
    the best of those (`best_run`) turned by `turns[j]` about [`symmetry_centre`][]
    ([`turned`][]; an inactive run, `fine_refine(..., active=False)`, where the turn is zero);
    then the last pass, from the best of all:

    - where that best shows no range noise, its polish against planes through the previous
      points (see [`polished`][]);
    - else, with `FineStage.symmetric` "finish" ([`finishes_two_way`][]) on a view that shows
      range noise (`_fine.fits_two_way`), the two-way finish: the same fit with the two-way
      residuals added. The fits before it run one-way, so that a noisy call pays for the
      two-way matching in one pass that starts at a converged fit instead of in every fit
      (docs, Findings: a two-way finish instead of two-way fits);
    - an inactive run otherwise.

    With `FineStage.symmetric` True, and "noisy" on a view that shows range noise, every fit
    is two-way. Each live run's `conflict` is
    filled in ([`free_space_conflict`][], against the two views' range maps), so that "best"
    here ([`best_run`][] with the config) and in the contests after it weighs fits far apart by
    what the views saw.

    A fit that reaches an earlier converged fit's result (within `_fine.JOIN_RADIUS`,
    [`joinable`][]) stops there and takes that result: the same minimum, found again without
    its last rounds.

    One `lax.scan` over the passes, so that the program holds one fine stage, not one per
    start: each copy cost about 1.3 s of tracing and compiling on the 2-core CPU. The passes
    run one after another, as separate calls would."""
    count = starts.shape[0]
    turns = jnp.zeros((0, 3), starts.dtype) if turns is None else turns.astype(starts.dtype)
    fits = count + turns.shape[0]
    passes = fits + has_last_pass(config)
    fine = problem.fine
    exact = exact_surface(fine)
    centre = symmetry_centre(fine.points, fine.normals, fine.valid, turns[0]) if turns.shape[0] else None
    views = view_maps(problem)
    can_polish = config.fine.anchor != "point"
    finishing = finishes_two_way(config)

    def one_pass(runs, i):
        last = i == fits
        turning = (i >= count) & ~last
        best = best_run(runs, fits, config)
        start = starts[jnp.minimum(i, count - 1)]
        if turns.shape[0]:
            turn = turns[jnp.clip(i - count, 0, turns.shape[0] - 1)]
            start = jnp.where(turning, turned(best_run(runs, count, config).params, turn, centre), start)
            active = ~turning | jnp.any(turn != 0)
        else:
            active = True
        noise_free = without_range_noise(best)
        polish = last & noise_free & can_polish
        finish = (last & ~noise_free & fits_two_way(config.fine, fine.noise)) if finishing else False
        start = jnp.where(last, best.params, start)
        active = jnp.where(last, polish | finish, active)
        run = fine_refine(
            problem,
            config,
            start,
            tree_select(polish, exact, fine),
            active=active,
            smooth=~polish,
            two_way=finish if finishing else ~polish,
            combine=~polish,
            joins=joinable(runs, i, fits),
        )
        conflict = jnp.where(run.inliers > 0, free_space_conflict(problem, run.params, views), jnp.nan)
        run = eqx.tree_at(lambda r: r.conflict, run, conflict.astype(run.conflict.dtype))
        run = tree_select(run.joined >= 0, joined_result(runs, run), run)
        return jax.tree.map(lambda stacked, x: stacked.at[i].set(x), runs, run), None

    runs, _ = jax.lax.scan(one_pass, FineResult.empty(passes, starts.dtype), jnp.arange(passes))
    return runs


def joinable(runs: FineResult, i: Int[Array, ""], fits: int) -> Float[Array, "k 6"]:
    """p (frame n) of the fits before pass i of [`fine_passes`][] that a later fit may join
    (`_fine.JOIN_RADIUS`): live (some inliers) and converged; NaN rows elsewhere, and
    everywhere for the last pass, which starts at the best fit and refines it."""
    index = jnp.arange(runs.params.shape[0])
    usable = (index < i) & (i < fits) & (runs.inliers > 0) & runs.converged
    return jnp.where(usable[:, None], runs.params, jnp.nan)


def joined_result(runs: FineResult, run: FineResult) -> FineResult:
    """The earlier fit of `runs` that `run` joined (`FineResult.joined`), with `run`'s own
    `steps` and `joined`."""
    earlier = _take(runs, run.joined)
    return eqx.tree_at(lambda r: (r.steps, r.joined), earlier, (run.steps, run.joined))


def within_reach(p: Float[Array, "6"], config: Config) -> Bool[Array, ""]:
    """Whether p (frame n, radians and metres) lies where the search can reach: within
    (1 + `recentre`) box half-widths of p = 0. The fine stage's result is dropped outside it, so
    that a slide along a free direction never carries the estimate out of the box."""
    return jnp.all(jnp.abs(p) <= (1 + config.search.recentre) * box_scale(config).astype(p.dtype))


@eqx.filter_jit
def estimate_problem(
    problem: Problem, config: Config, key: PRNGKeyArray, guess: Float[Array, "6"] | None = None
) -> Estimate:
    """[`estimate`][] on a prepared [`jaxpose.Problem`][] (pure, jitted, vmappable).

    `guess`: p (frame n, radians and metres) of a motion known beforehand, such as a
    tracker's prediction; the second fit of the fine stage (`FineStage.from_rest`) starts
    there instead of at rest. Not used by the capture stage."""
    if config.so3 is not None:
        return _finish(problem, config, *_capture_stages(problem, config))
    return _finish(problem, config, *_box_stages(problem, config, key, guess))


def _box_stages(problem: Problem, config: Config, key: PRNGKeyArray, guess=None):
    """CMA-ES in the search box, the refine where the config has one, and the fine stage from
    their result (and from rest): the stages of every preset but `Config.capture()`."""
    glob = restarted_search(problem, config, key)
    if config.refine is None:
        # No refine: `_finish` scores the search's best together with the estimate. That best
        # lies on coarse cells: it counts as converged only where no fine stage follows it (the
        # paper's method); a fine result dropped for it leaves no converged fit.
        loc, p, converged = glob.params, glob.params, jnp.asarray(config.fine is None)
    else:
        loc = local_refine(problem, config, glob.params)
        p, converged = loc.params, loc.converged
    fine, fine_kept = None, jnp.asarray(False)
    ambiguous, alternative = jnp.asarray(False), p
    spread = jnp.zeros((), p.dtype)
    candidates = p[None], jnp.ones(1, p.dtype), jnp.ones(1, bool)
    if config.fine is None:
        hard = hard_score(p, problem)
    else:
        starts = [p]
        if config.fine.from_rest:
            starts.append(jnp.zeros_like(p) if guess is None else guess.astype(p.dtype))
        if config.fine.from_principal:
            starts.append(principal_start(problem).astype(p.dtype))
        turns = symmetry_turns(problem.frame, config) if config.fine.turn_deg > 0 else None
        runs = fine_passes(problem, config, jnp.stack(starts), turns)
        fine = other = _take(runs, 0)
        if config.fine.from_rest:
            rest = _take(runs, 1)
            ambiguous = equally_good_and_apart(fine, rest, config)
            rest_wins = prefers(fine, rest, config)
            fine, other = tree_select(rest_wins, rest, fine), tree_select(rest_wins, fine, rest)
        fits = len(starts) + (0 if turns is None else turns.shape[0])
        # The principal start, then the turned runs, each a challenger to the best so far.
        for i in range(1 + config.fine.from_rest, fits):
            fine, other, ambiguous = contest(fine, other, ambiguous, _take(runs, i), config)
        alternative = other.params
        if has_last_pass(config):
            fine = finished(fine, runs, fits, config)
        # The fine stage fits surfaces, not patterns: where the visible faces leave a direction
        # free it can slide along it (tens of centimetres along a face on random views). Its
        # result is kept unless the method's reference score drops by more than the guard;
        # then its start, the refine's result or the search's best, stands.
        # Both hard scores in one batch: one traced copy of the objective.
        hard, fine_hard = score_batch(jnp.stack([p, fine.params]), problem, "hard")
        fine_kept = (fine_hard >= hard - config.fine.guard) & within_reach(fine.params, config)
        # When kept, the fine stage's convergence is the one that counts (BFGS on the soft
        # objective may stop on a kink short of its tolerance and not matter).
        p = jnp.where(fine_kept, fine.params, p)
        converged = jnp.where(fine_kept, fine.converged, converged)
        hard = jnp.where(fine_kept, fine_hard, hard)
        spread = jnp.where(fine_kept, fit_spread(fine, runs, fits), 0.0)
        candidates = (
            jnp.stack([p, other.params]),
            jnp.stack([jnp.where(fine_kept, fine.inliers, 0.0), other.inliers]),
            jnp.stack([jnp.asarray(True), rotations_apart(p, other.params, config) & fine_kept]),
        )
    return glob, loc, p, converged, hard, fine, fine_kept, ambiguous & fine_kept, alternative, candidates, spread


def _capture_stages(problem: Problem, config: Config):
    """The capture stage over the whole rotation group (`jaxpose._capture`), then the configured
    fine stage from its best hypothesis."""
    cap = capture_search(problem, config)
    runs = fine_passes(problem, config, cap.params[:1])
    fine = _take(runs, 0)
    if has_last_pass(config):
        fine = finished(fine, runs, 1, config)
    p = fine.params
    rest = cap.params[1:]
    runner_up = jnp.argmax(jnp.where(cap.distinct[1:], cap.score[1:], -jnp.inf))
    rival = jnp.max(jnp.where(cap.distinct[1:], cap.consistency[1:], -jnp.inf))
    ambiguous = rival >= cap.consistency[0] - config.so3.tie
    glob = GlobalResult(
        cap.grid_best,
        cap.grid_score,
        cap.grid_score[None],
        cap.evaluations,
        jnp.asarray(False),
        jnp.asarray(0, jnp.int32),
        jnp.asarray(0, jnp.int32),
    )
    loc = cap.refined[0]  # scored by `_finish` together with the estimate
    alternative = jnp.where(cap.distinct[1 + runner_up], rest[runner_up], p)
    candidates = (cap.params.at[0].set(p), cap.score, cap.distinct)
    fine_kept = jnp.all(jnp.isfinite(p))
    spread = jnp.zeros((), p.dtype)  # one start: no other fit to compare
    hard = hard_score(p, problem)
    return glob, loc, p, fine.converged, hard, fine, fine_kept, ambiguous, alternative, candidates, spread


def is_uncertain(
    covariance: Float[Array, "6 6"], config: Config, spread: Float[Array, ""] | float = 0.0
) -> Bool[Array, ""]:
    """Whether a motion covariance (camera frame; rotation vector in radians, then metres)
    promises less than a success does: its largest rotation standard deviation, combined in
    quadrature with half the `spread` of equally good fits (radians, [`fit_spread`][]),
    exceeds `Thresholds.max_rotation_std_deg`, or it is not finite (then it promises
    nothing)."""
    std = jnp.sqrt(rotation_std(covariance) ** 2 + (jnp.asarray(spread) / 2) ** 2)
    return ~(jnp.degrees(std) <= config.thresholds.max_rotation_std_deg)


def held_motion(
    problem: Problem, config: Config, p: Float[Array, "6"], matches: FitMatches | None = None
) -> tuple[RotationHold, SlideHold]:
    """[`face_holds`][jaxpose._fine.face_holds] of a fit p (frame n), the turn's axis and the
    translation's direction turned into the camera frame c (the frame of `Estimate.rotation`'s
    rotation vector and of `Estimate.translation`). `matches`: `_fine.fit_matches` at p, where
    the caller has them."""
    hold, slide = face_holds(problem, config, p, matches)
    axes = problem.frame.axes
    return RotationHold(hold.lever, axes @ hold.axis), SlideHold(slide.grip, axes @ slide.direction)


def barely_held(hold: RotationHold, slide: SlideHold, config: Config) -> Bool[Array, ""]:
    """Whether the matched faces barely hold some turn (`RotationHold.lever` below
    `Thresholds.min_rotation_lever`) or some translation (`SlideHold.grip` below
    `Thresholds.min_translation_grip`)."""
    thresholds = config.thresholds
    return (hold.lever < thresholds.min_rotation_lever) | (slide.grip < thresholds.min_translation_grip)


def _finish(
    problem, config, glob, loc, p, converged, hard, fine, fine_kept, ambiguous, alternative, candidates, spread
) -> Estimate:
    """The status (first matching condition of a fixed priority) and the estimate's fields.

    `loc` is the refine's `LocalResult`, or, where no refine ran, the p (frame n) that holds its
    place (the search's best, or the capture stage's best refined mode): that one is scored
    here, in one batch with the estimate (one traced copy of the soft objective in the program
    instead of two)."""
    finite = jnp.all(jnp.isfinite(p)) & jnp.isfinite(hard)
    p = jnp.where(finite, p, jnp.zeros_like(p))
    covariance, residual_scale, uncertain, hold, slide = None, None, jnp.asarray(False), None, None
    if fine is not None:
        # One voxel search of the fit's matches for both the covariance and the holds.
        matches = fit_matches(problem, config, p)
        covariance, residual_scale = motion_uncertainty(problem, config, p, matches)
        hold, slide = held_motion(problem, config, p, matches)
        uncertain = is_uncertain(covariance, config, spread) | barely_held(hold, slide, config)
    conditions = [
        (problem.status != 0, Status.degenerate),
        (~finite, Status.non_finite),
        (hard < config.thresholds.min_score, Status.low_score),
        (glob.at_edge, Status.at_box_edge),
        (ambiguous, Status.ambiguous),
        (uncertain, Status.uncertain),
        (~converged, Status.not_converged),
    ]
    result = Status.success
    for condition, item in reversed(conditions):
        result = Status.where(condition, item, result)
    R, t = motion_from_displacement(problem.frame.origin, problem.frame.axes, p)
    params, score, distinct = candidates
    params = jnp.where(jnp.all(jnp.isfinite(params), axis=1, keepdims=True), params, p[None])
    if isinstance(loc, LocalResult):
        soft = soft_score(p, problem)
    else:
        soft, start_soft = score_batch(jnp.stack([p, loc]), problem, "soft")
        loc = LocalResult(loc, start_soft, jnp.asarray(True), jnp.asarray(0, jnp.int32))
    return Estimate(
        params=p,
        rotation=R,
        translation=t,
        frame=problem.frame,
        hard=jnp.where(finite, hard, 0.0),
        soft=soft,
        result=result,
        search=glob,
        refine=loc,
        fine=fine,
        fine_kept=fine_kept,
        ambiguous=ambiguous,
        alternative=jnp.where(jnp.all(jnp.isfinite(alternative)), alternative, p),
        hypotheses=hypotheses_of(problem.frame, params.at[0].set(p), score, distinct),
        covariance=covariance,
        spread=jnp.where(finite, spread, 0.0),
        hold=hold,
        slide=slide,
        residual_scale=residual_scale,
    )


def estimate(prev: Cloud, curr: Cloud, config: Config | None = None, *, key: PRNGKeyArray) -> Estimate:
    """Displacement of the target between the previous and the current cloud.

    **Arguments:**

    - `prev`, `curr`: the two [`jaxpose.Cloud`][]s, camera frame, metres.
    - `config`: a [`jaxpose.Config`][] (default `Config()`).
    - `key`: PRNG key of the global search; the same key gives the same result.

    **Returns:**

    An [`Estimate`][]. Pure; works under `jax.jit` and `jax.vmap` over pairs and keys. At the
    Python boundary an unusable pair raises ValueError (see `Problem.build`); under jit it
    comes back with result `Status.degenerate` and never as a success.
    """
    config = Config() if config is None else config
    if not is_concrete(prev, curr):
        return estimate_problem(Problem.build(prev, curr, config), config, key)
    prev.check("previous cloud")
    curr.check("current cloud")
    check_range(prev, curr, config)
    prev, curr = prev.floating(), curr.floating()
    config = sized_config(prev, curr, config)
    est, status, frame_status = run_growing(lambda grown: _estimate_pair(prev, curr, grown, key), config)
    raise_for_codes(int(status), int(frame_status))
    return est


def _build_and_estimate(prev: Cloud, curr: Cloud, config: Config, key: PRNGKeyArray):
    problem = _build(prev, curr, config)
    return estimate_problem(problem, config, key), problem.status, problem.frame.status


_estimate_pair = BoundedJit(_build_and_estimate)
"""Build, search, refine and fine stage as one compiled program per capacity bucket (the most
recently used ones kept in memory, see `jaxpose._programs`)."""


__all__ = [
    "AMBIGUOUS",
    "UNCERTAIN",
    "STATUS_NAME",
    "STATUS_TEXT",
    "Estimate",
    "Hypotheses",
    "Status",
    "estimate",
    "estimate_problem",
]
