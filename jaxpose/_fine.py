"""Fine stage: point-to-plane least squares on the visible surface or the points near the
cutting planes (ours).

The pattern objectives compare cell occupancies, so their optimum is resolved to a fraction
of a cell (d = 2.6 cm) and lands 0.1–0.6° from the truth on the paper's pairs. The fine stage
measures how far each current point lies from the previous *surface*, over the whole visible
surface (the default: slabs of infinite width) or, as the method's data reduction, only the
points near the cutting planes:

- previous side (built once, in [`jaxpose.Problem.build`][]): the previous points within
  `FineStage.prev_slab`·d of a cutting plane, in frame n, thinned evenly to
  `FineStage.prev_points` (by default `FineStage.points`), each with the normal of a plane fitted to
  its `FineStage.neighbours` nearest such points (the direction of least scatter); the
  `FineStage.planar_fraction` most planar neighbourhoods (smallest / middle scatter
  eigenvalue) keep their point: all of them by default, edges and corners included, whose
  planes of least scatter hold the slides along the faces; `Config.paper()` drops the
  least planar 30 %;
- current side (chosen once, at the start p₀): the current points within `FineStage.curr_slab`·d
  of a cutting plane of frame ν(p₀), thinned evenly to `FineStage.points`;
- residual of current point i at p: nᵀ(qᵢ(p) − a), with qᵢ(p) its coordinates in frame ν
  and (a, n) the nearest previous point and its normal — zero where the moved surfaces
  coincide; with `FineStage.anchor` "hybrid" (the default) the plane of a face-like
  neighbourhood goes through its centroid instead of a (it averages the range noise), and
  across edges and corners through a (where the centroid lies inside the body).
  Points farther than `FineStage.inlier` from every previous point (surface seen only in one
  cloud) get weight 0.
- two-way (`FineStage.symmetric`; by default only on views that show range noise,
  `FineCloud.noise`): previous points (`BACK_POINTS`, thinned evenly) are also matched to
  their nearest current points, and their distances to those points' planes, fitted to the
  current cloud (`back_side`), join the residuals (`back_residuals`); they are matched in
  the same phases as the forward matches (`back_matches`, `GRAPH_SHIFT`).

This is point-to-plane ICP (Chen & Medioni 1992) on the selected points:
rounds of nearest-neighbour matching (a voxel search, or, while the points have moved
little since the last search, a step of descent on the previous points' neighbour graph:
`GRAPH_SHIFT`), each followed by optimistix's Gauss–Newton on the matched residuals. Its
basin is a few degrees, so it follows the global search and the soft refine and never
replaces them. Lengths in metres, angles in radians, frame n.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from ._config import Config, FineStage
from ._neighbours import (
    VoxelGrid,
    certified_in_graph,
    graph_radius,
    k_nearest,
    nearest,
    nearest_in_graph,
    spread_subset,
    voxel_grid,
    voxel_spacing,
    windows,
)
from ._poses import PARAMETER_SCALE
from ._rotations import into_moved_frame, rotate_components, rotation

ROUND_TOL = 1e-3
"""A round that moves p by less than this (units of 1° and 1 cm: 0.001°, 0.01 mm) ends the
stage as converged. Far below the stage's accuracy; tighter, nearest-neighbour matches that
flip between two equally near points kept some pairs cycling to the round limit."""

RESIDUAL_UNIT = 1e-3
"""Residuals are expressed in millimetres, so that the solver's tolerances read in mm."""

NEIGHBOUR_VOXEL = 2.0
"""Voxel edge of the neighbour search, in sampling steps of the previous points (their median
nearest-neighbour distance): a voxel holds about four points of a surface seen head-on."""

NEIGHBOUR_SLOTS = 16
"""Points read from each column of three voxels (`_neighbours.candidates`)."""

ROBUST_SCALE = 3.0
"""Cauchy weights 1 / (1 + (r / c)²) with c = this × the round's robust residual scale
(1.4826 × median |r| of the inliers), at least `ROBUST_FLOOR`: flying pixels, surface seen in
one cloud only and mismatched edges weigh little, and the noise's own spread keeps weight."""

POINT_WEIGHT = 0.01
"""Weight of the point-to-point residuals beside the point-to-plane one (both in metres):
where the visible faces leave a direction free (a slide along an edge or a face), the
point-to-plane residuals are flat and the point-to-point ones, though coarser (they carry
the sampling step), fix it; elsewhere the plane term dominates."""

NOISE_STEP = 0.5
"""A round also ends the stage as converged when its step Δp is shorter than this many standard
deviations of the result: ‖J Δp‖ / σ̂ ≤ `NOISE_STEP`, with J the Jacobian of the round's
weighted residuals and σ̂ their weighted RMS (so that ‖J Δp‖² / σ̂² = Δpᵀ Σ⁻¹ Δp for the
least-squares covariance Σ = σ̂² (JᵀJ)⁻¹). Under range noise the matches keep changing by
amounts the data cannot resolve, most along the directions the visible faces leave weak (a
slide along a face); a step within half a standard deviation there is noise, not progress,
and "not converged" must mark an unreliable result, not a noisy pair. Noise-free, σ̂ is at
most round-off and `ROUND_TOL` decides."""

SIGMA_FLOOR = 1e-4
"""Smallest residual scale σ̂ of [`fine_covariance`][], metres: on noise-free views the
residuals are round-off (≈ 1e-7 m in float32), and σ̂² (JᵀJ)⁻¹ at that scale is not positive
definite in float32, so the tracker would refuse every noise-free measurement. 0.1 mm is
below the accuracy any registration of these clouds reaches (the sampling step is ≈ 1 cm)."""

ROBUST_FLOOR = 5e-4
"""Smallest Cauchy scale c, metres: noise-free residuals do not shrink it to nothing."""

JOIN_RADIUS = 0.1
"""A fit that comes within this of an earlier converged fit's result, in every parameter
(units of 1° and 1 cm: 0.1° and 1 mm, `PARAMETER_SCALE`), stops there and takes that result
([`fine_refine`][]'s `joins`): it has entered the same minimum, and the rounds it would spend
converging to it again cost as much as the earlier fit's last rounds. Minima that the data
tell apart lie farther apart than this (the realistic benchmark's closest distinct fits of one
pair were 0.76° apart)."""


class FineCloud(eqx.Module):
    """Previous points near the cutting planes with their surface planes (frame n, metres).

    - `points`: `(3, K)` the selected previous points, structure of arrays, zero padded.
    - `normals`: `(3, K)` unit normals of the planar ones (zero elsewhere).
    - `offsets`: `(K,)`, the plane of point k is {x : normals[:, k]ᵀ x = offsets[k]}; it goes
      through the point, or through its neighbourhood's centroid (`FineStage.anchor`; with
      "hybrid", the centroid for the `planar` points and the point for the others).
    - `point_offsets`: `(K,)`, the same planes through the points themselves (the exact
      anchor of a noise-free view, used by [`exact_surface`][]).
    - `valid`: `(K,)` mask (selected and among the `FineStage.planar_fraction` most planar).
    - `planar`: `(K,)` mask: selected and among the `EXACT_PLANAR_FRACTION` most planar, the
      planes [`exact_surface`][] keeps.
    - `grid`: the voxel grid of the selected points (planar or not) that the matching
      searches (`_neighbours`); its voxel is `NEIGHBOUR_VOXEL` sampling steps.
    - `graph`: `(K, k)` the `FineStage.neighbours` nearest selected points of each (indices
      into `points`; the point's own nearest where fewer were in reach): the neighbourhoods
      of the normal fits, which the later rounds' matching descends ([`GRAPH_SHIFT`][]).
    - `radius`: `(K,)` metres: every selected point outside a point's `graph` row lies at
      least this far from it (`_neighbours.graph_radius`; 0 for padding), which certifies the
      finish rounds' graph matches ([`CERTIFIED_BUFFER`][]).
    - `noise`: scalar, metres: the view's range noise as its faces show it, a low quantile
      over the face-like neighbourhoods (`planar`) of the RMS distance of their points to
      their plane ([`view_noise`][]). Below `EXACT_RMS` the view counts as noise-free, and
      the default `FineStage.symmetric` ("noisy") fits it one-way.
    """

    points: Float[Array, "3 K"]
    normals: Float[Array, "3 K"]
    offsets: Float[Array, " K"]
    point_offsets: Float[Array, " K"]
    valid: Bool[Array, " K"]
    planar: Bool[Array, " K"]
    grid: VoxelGrid
    graph: Int[Array, "K k"]
    radius: Float[Array, " K"]
    noise: Float[Array, ""]


@runtime_checkable
class SurfaceProblem(Protocol):
    """What the fine stage and its covariance read of a problem: a `jaxpose.Problem`, or the
    model side of a registration against a body model (`jaxpose.tracking._against_model`).

    - `frame`: the plane frame n (`PlaneFrame`), in which the parameters p live.
    - `fine`: the previous side (`FineCloud`, frame n).
    - `curr`, `curr_valid`: the current points (frame n, `(3, M)`) and their mask.
    - `fine_curr`: the smoothed current side (`CurrentSide`) or None.
    - `fine_back`: the current points with their planes (`FineCloud`, frame n), for two-way
      residuals (`FineStage.symmetric`), or None.
    - `d`, `planes`: the cell size (m) and the cutting planes, for the slabs.
    """

    frame: object
    fine: FineCloud
    curr: Array
    curr_valid: Array
    fine_curr: object
    fine_back: object
    d: Array
    planes: tuple


class FineResult(eqx.Module):
    """Result of [`fine_refine`][].

    - `params`: p in frame n (radians, metres).
    - `converged`: the last round moved p by at most `ROUND_TOL`, or by less than
      `NOISE_STEP` standard deviations (within `FineStage.rounds`).
    - `steps`: Gauss–Newton steps taken, all rounds.
    - `inliers`: fraction of the selected current points within `FineStage.inlier` of the
      previous points (whether or not the nearest has a plane: a fit against fewer planes,
      as [`exact_surface`][]'s, explains the same cloud as well), with the last round's
      matches (made where that round started, within `ROUND_TOL` of `params` when
      converged); 0 when none was selected.
    - `rms`: root mean square point-to-plane residual at `params` of the inliers whose nearest
      has a plane, each weighted by its Cauchy weight, metres; of the raw current points
      (`CurrentSide.points`) also where the fit used the smoothed ones, so that it measures
      the range noise.
    - `planar_rms`: the same over the inliers matched to the most planar previous points
      (`FineCloud.planar`): whether a view shows range noise (`EXACT_RMS`), without the
      edges' planes, which miss a noise-free surface by up to millimetres.
    - `used`: number of selected current points.
    - `conflict`: the share of both clouds' points that the fit puts where the other view saw
      through (`jaxpose._estimate.free_space_conflict`); NaN where not judged: `fine_refine`
      leaves it so, `jaxpose._estimate.fine_passes` fills it in for each live run.
    - `joined`: the row of `fine_refine`'s `joins` whose result this fit reached
      (`JOIN_RADIUS`) and stopped at, −1 where it ran to its own end; `fine_passes` then
      gives it that earlier fit's result.
    """

    params: Float[Array, "6"]
    converged: Bool[Array, ""]
    steps: Int[Array, ""]
    inliers: Float[Array, ""]
    rms: Float[Array, ""]
    planar_rms: Float[Array, ""]
    used: Int[Array, ""]
    conflict: Float[Array, ""]
    joined: Int[Array, ""]

    @classmethod
    def empty(cls, count: int, dtype) -> FineResult:
        """`count` blank results stacked on a leading axis, of the types [`fine_refine`][]
        returns for floats of `dtype` (`conflict` NaN, `joined` −1, the rest zero): the carry of
        a loop that fills one row per fit, built without tracing a fit to learn its types
        (tracing one takes about a second on a 2-core CPU)."""
        zero = jnp.zeros((), dtype)
        blank = cls(
            params=jnp.zeros(6, dtype),
            converged=jnp.asarray(False),
            steps=jnp.asarray(0, jnp.int32),
            inliers=zero,
            rms=zero,
            planar_rms=zero,
            used=jnp.asarray(0, jnp.int32),
            conflict=jnp.full((), jnp.nan, dtype),
            joined=jnp.asarray(-1, jnp.int32),
        )
        return jax.tree.map(lambda x: jnp.broadcast_to(x, (count, *x.shape)), blank)


def slab_distance(points: Float[Array, "3 N"], planes, d) -> Float[Array, " N"]:
    """Distance of each point (frame n or ν, SoA) to the nearest cutting plane."""
    return jnp.min(jnp.stack([jnp.abs(points[j] - offset * d) for j, offset in planes]), axis=0)


def smallest_eigen(
    S: Float[Array, "K 3 3"],
) -> tuple[Float[Array, " K"], Float[Array, " K"], Float[Array, "K 3"], Bool[Array, " K"]]:
    """Smallest and middle eigenvalues of symmetric 3 × 3 matrices, the unit eigenvector of the
    smallest, and whether it is defined (False where the smallest eigenvalue is not single,
    e.g. collinear or coincident points: then the vector is 0).

    Closed form (trigonometric eigenvalues, then the largest cross product of two rows of
    S − λ_min I): batched `jnp.linalg.eigh` on 3 × 3 matrices is a loop of small
    decompositions on the CPU, this is a few dozen multiply-adds per matrix; it is as accurate
    (`tests/test_fine.py` checks it against eigh). The middle eigenvalue, used only for the
    planarity ratio, is resolved to ≈ √eps relative where the two largest coincide."""
    s00, s11, s22 = S[:, 0, 0], S[:, 1, 1], S[:, 2, 2]
    s01, s02, s12 = S[:, 0, 1], S[:, 0, 2], S[:, 1, 2]
    q = (s00 + s11 + s22) / 3
    a, b, c = s00 - q, s11 - q, s22 - q
    p = jnp.sqrt((a * a + b * b + c * c + 2 * (s01 * s01 + s02 * s02 + s12 * s12)) / 6)
    inv = 1 / jnp.where(p > 0, p, 1)
    a, b, c, d, e, f = a * inv, b * inv, c * inv, s01 * inv, s02 * inv, s12 * inv
    half_det = (a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)) / 2
    angle = jnp.arccos(jnp.clip(half_det, -1, 1)) / 3
    largest = q + 2 * p * jnp.cos(angle)
    smallest = q + 2 * p * jnp.cos(angle + 2 * jnp.pi / 3)
    middle = 3 * q - largest - smallest
    M = S - smallest[:, None, None] * jnp.eye(3, dtype=S.dtype)[None]
    rows = M[:, 0], M[:, 1], M[:, 2]
    crosses = jnp.stack([jnp.cross(rows[0], rows[1]), jnp.cross(rows[0], rows[2]), jnp.cross(rows[1], rows[2])], 1)
    norms = jnp.linalg.norm(crosses, axis=2)
    best = jnp.argmax(norms, axis=1)
    vector = jnp.take_along_axis(crosses, best[:, None, None], axis=1)[:, 0]
    size = jnp.take_along_axis(norms, best[:, None], axis=1)[:, 0]
    # The eigenvector is defined where the smallest eigenvalue is single. Near a double root the
    # arccos above resolves the eigenvalues only to ≈ √eps · p, hence the margin.
    defined = (middle - smallest) > 30 * jnp.sqrt(jnp.finfo(S.dtype).eps) * p
    return smallest, middle, jnp.where(defined[:, None], vector / jnp.where(defined, size, 1)[:, None], 0.0), defined


class Neighbourhoods(NamedTuple):
    """The plane fitted to each point's neighbourhood ([`neighbourhood_planes`][]), frame of the
    points, metres: `centroid` (3, K), the `smallest` and `middle` scatter eigenvalues (K,),
    the unit `normal` (3, K) (unoriented; 0 where undefined), whether the fit is defined
    (`enough`: at least 3 neighbours and a single smallest eigenvalue), the neighbours'
    `index` (K, k) into the points (the nearest one repeated where fewer were in reach) and
    the `radius` (K,) within which `index` holds every point (`_neighbours.graph_radius`)."""

    centroid: Float[Array, "3 K"]
    smallest: Float[Array, " K"]
    middle: Float[Array, " K"]
    normal: Float[Array, "3 K"]
    enough: Bool[Array, " K"]
    index: Int[Array, "K k"]
    radius: Float[Array, " K"]


def neighbourhood_planes(
    grid: VoxelGrid, points: Float[Array, "3 N"], queries: Float[Array, "3 K"], k: int
) -> Neighbourhoods:
    """The plane through the `k` nearest neighbours of each query (SoA) among `points`, the
    points `grid` was built from: centroid, scatter eigenvalues and normal."""
    read = windows(grid, queries, NEIGHBOUR_SLOTS)
    nb, d2 = k_nearest(grid, queries, k, NEIGHBOUR_SLOTS, read)
    found = jnp.isfinite(d2).astype(queries.dtype)  # neighbours within the search's reach
    hood = points[:, nb]  # (3, K, k)
    counts = jnp.maximum(jnp.sum(found, axis=1), 1)
    centroid = jnp.sum(hood * found[None], axis=2, keepdims=True) / counts[None, :, None]
    centred = (hood - centroid) * found[None]
    scatter = jnp.einsum("ikn,jkn->kij", centred, centred)
    smallest, middle, normal, defined = smallest_eigen(scatter)
    enough = (jnp.sum(found, axis=1) >= 3) & defined
    index = jnp.where(jnp.isfinite(d2), nb, nb[:, :1])
    radius = graph_radius(grid, queries, d2, read, NEIGHBOUR_SLOTS)
    return Neighbourhoods(centroid[:, :, 0], smallest, middle, normal.T, enough, index, radius)


def _most_planar(hood: Neighbourhoods, live: Bool[Array, " K"]):
    """A function of a fraction f (0–1) giving the mask of the f most planar live
    neighbourhoods with a defined plane. Planarity: smallest / middle scatter eigenvalue,
    ranked rather than thresholded, so that it works whatever the noise (with 1 cm range noise
    on N5 every neighbourhood scored above 0.01, noise-free the faces score ~0 and the edges
    high)."""
    usable = live & hood.enough
    flatness = jnp.where(usable, hood.smallest / jnp.maximum(hood.middle, jnp.finfo(hood.middle.dtype).tiny), jnp.inf)
    count = jnp.sum(usable)
    ranked = jnp.sort(flatness)

    def most_planar(fraction):
        kth = jnp.clip(jnp.ceil(fraction * count).astype(jnp.int32) - 1, 0, ranked.shape[0] - 1)
        return usable & (flatness <= ranked[kth])

    return most_planar


def _planes_from_every_point(
    A: Float[Array, "3 N"],
    near: Bool[Array, " N"],
    P: Float[Array, "3 K"],
    thinned: Neighbourhoods,
    k: int,
    centroids_only: bool = False,
) -> Neighbourhoods:
    """The planes of the selected points `P` fitted to their `k` nearest points among every
    previous point `A` (`near`), where the selection thinned them (more than K points);
    `thinned` (the planes among the selected points) where it did not, as those are the same.

    The selection is evenly spread, so on a view of more than K points its k nearest span a
    wider patch than the cloud's own: a plane through their centroid lies farther inside a
    curved surface, and its normal turns with the patch. Among every point the patch is the
    sensor's own sampling, at the cost of one more neighbour search over a grid of every point.
    Only the planes change: the graph of the selected points (`FineCloud.graph`, `radius`)
    stays the thinned one, which the matching descends. `centroids_only` ("all_centroids"):
    keep the thinned normals and scatter (so the planarity ranks) and take only the centroids
    among every point."""
    count = jnp.sum(near)

    def every_point():
        grid = voxel_grid(A, near, NEIGHBOUR_VOXEL * voxel_spacing(A, near))
        hood = neighbourhood_planes(grid, A, P, min(k, A.shape[1]))
        if centroids_only:
            return thinned._replace(centroid=hood.centroid)
        return hood._replace(index=thinned.index, radius=thinned.radius)

    return jax.lax.cond(count > P.shape[1], every_point, lambda: thinned)


def fine_cloud(prev_n: Float[Array, "N 3"], valid: Bool[Array, " N"], config: Config, planes, d) -> FineCloud:
    """The previous side of the fine stage from the previous points in frame n (rows)."""
    stage = FineStage(points=1) if config.fine is None else config.fine  # None: one empty slot
    K = stage.points if stage.prev_points is None else min(stage.prev_points, prev_n.shape[0])
    A = jnp.where(valid[:, None], prev_n, 0.0).T
    near = valid & (slab_distance(A, planes, d) <= stage.prev_slab * d)
    idx, live = spread_subset(near, K)
    P = A[:, idx]
    grid = voxel_grid(P, live, NEIGHBOUR_VOXEL * voxel_spacing(P, live))
    hood = neighbourhood_planes(grid, P, P, min(stage.neighbours, K))
    graph = hood.index
    if stage.plane_source != "selected":
        hood = _planes_from_every_point(A, near, P, hood, stage.neighbours, stage.plane_source == "all_centroids")
    centroid, normal = hood.centroid, hood.normal
    # Keep the `FineStage.planar_fraction` most planar points (all by default).
    most_planar = _most_planar(hood, live)
    ok = most_planar(stage.planar_fraction)
    # A plane through the neighbourhood's centroid averages the range noise of
    # `FineStage.neighbours` points. Through the raw noisy point, the nearest-neighbour match
    # prefers previous points whose noise moved them towards the current point, which biased
    # registrations of N5 with 1 cm noise in proportion to the motion (docs, Findings: the fine
    # stage's anchor). Across an edge or a corner, though, the centroid lies inside the body and
    # its plane below the surface, so "hybrid" takes the centroid only for the face-like
    # neighbourhoods (`EXACT_PLANAR_FRACTION` most planar) and the point elsewhere. Matching and
    # the inlier test use the points.
    face = ok & most_planar(EXACT_PLANAR_FRACTION)
    anchor = {"centroid": centroid, "point": P, "hybrid": jnp.where(face[None], centroid, P)}[stage.anchor]
    offset = jnp.sum(normal * anchor, axis=0)
    point_offset = jnp.sum(normal * P, axis=0)
    noise = view_noise(hood.smallest, min(stage.neighbours, K), face)
    return FineCloud(
        jnp.where(live, P, 0.0),
        jnp.where(ok, normal, 0.0),
        jnp.where(ok, offset, 0.0),
        jnp.where(ok, point_offset, 0.0),
        ok,
        face,
        grid,
        graph.astype(jnp.int32),
        jnp.where(live, hood.radius, 0.0),
        noise,
    )


NOISE_QUANTILE = 0.25
"""The quantile of the face-like neighbourhoods' plane RMS that [`view_noise`][] reports. A
low quantile, because a noise-free view's curvature raises the RMS of some neighbourhoods (those
across the mesh debris's shallow creases, or on the upper stage's curved wall), never its
flattest quarter; range noise raises all of them. On two draws of the realistic benchmark
(seeds 1 and 2, 28 noise-free and 28 views at σ 0.5 cm) it was 0–0.87 mm noise-free (the debris
the most) and 0.47–4.0 mm at σ 0.5 cm (below 1 mm on three views: two of N1, one of the
debris)."""


def view_noise(smallest: Float[Array, " K"], k: int, face: Bool[Array, " K"]) -> Float[Array, ""]:
    """A view's range noise (metres) from its neighbourhood planes: the `NOISE_QUANTILE`
    quantile over the face-like neighbourhoods (`face`) of the RMS distance of their `k` points
    to their plane, √(smallest scatter eigenvalue / k) (the scatter is a sum over the points).
    Noise-free it is the faces' curvature (r²/8R for a patch of radius r on a surface of
    radius R); under range noise σ, about σ times the cosine of the incidence angle. 0 where no
    neighbourhood is face-like."""
    rms = jnp.sqrt(jnp.maximum(smallest, 0.0) / k)
    level = jnp.nanquantile(jnp.where(face, rms, jnp.nan), NOISE_QUANTILE)
    return jnp.where(jnp.any(face), level, 0.0)


SMOOTHED_FRACTION = 0.7
"""Fraction of the current points, those whose neighbourhoods are the most planar, that
[`current_side`][] smooths: the faces, as the previous side's `EXACT_PLANAR_FRACTION`; across
edges and corners the plane of least scatter misses the surface."""


class CurrentSide(eqx.Module):
    """The current side of the fine stage over the whole visible surface (frame n, metres):
    the current points thinned evenly to `FineStage.points`, built once in
    [`jaxpose.Problem.build`][] (`Problem.fine_curr`).

    - `points`: `(3, S)` the selected current points, structure of arrays, zero padded.
    - `smoothed`: `(3, S)` the same points, the face-like ones (`SMOOTHED_FRACTION` most
      planar neighbourhoods) moved along their neighbourhood's normal onto the plane fitted
      to their `FineStage.neighbours` nearest current points, among all the current points,
      not only the selected ones; the others as they are.
    - `live`: `(S,)` mask of the selected slots.

    Why: the residual nᵀ(q − a) carries the range noise of the current point q in full,
    while the previous side's plane averages its neighbourhood's ("hybrid" anchor). On a
    face, projecting q onto its own neighbourhood's plane removes the noise along the normal
    and keeps q's place on the surface, and it draws on the current points the thinning left
    out. On a curved face the plane through the centroid lies about r²/2R inside the
    surface, as the previous side's face planes do. Edges and corners keep their points, as
    the previous side's planes there go through the points."""

    points: Float[Array, "3 S"]
    smoothed: Float[Array, "3 S"]
    live: Bool[Array, " S"]


def current_side(curr: Float[Array, "3 M"], valid: Bool[Array, " M"], config: Config) -> CurrentSide | None:
    """The fine stage's current side ([`CurrentSide`][]) from the current points in frame n
    (SoA, metres), or None where the config does not smooth it
    (`FineStage.smooth_current`): then [`select_current`][] selects at each run's start."""
    if config.fine is None or not config.fine.smooth_current:
        return None
    idx, live = spread_subset(valid, config.fine.points)
    b = jnp.where(live[None], curr[:, idx], 0.0)
    grid = voxel_grid(curr, valid, NEIGHBOUR_VOXEL * voxel_spacing(curr, valid))
    hood = neighbourhood_planes(grid, curr, b, config.fine.neighbours)
    face = _most_planar(hood, live)(SMOOTHED_FRACTION)
    height = jnp.sum(hood.normal * (b - hood.centroid), axis=0)
    smoothed = jnp.where(face[None], b - hood.normal * height[None], b)
    return CurrentSide(b, smoothed, live)


def back_side(
    curr: Float[Array, "3 M"], valid: Bool[Array, " M"], config: Config, planes, d, noise
) -> FineCloud | None:
    """The current points (frame n, SoA, metres) with their planes, as [`fine_cloud`][] builds
    the previous side's, for the two-way residuals of `FineStage.symmetric` and the
    plane-to-plane residuals of `FineStage.residual`; None where the config asks for neither.
    With the whole surface on both sides its slot s holds the current point that
    [`select_current`][] puts in slot s (the same even thinning of the same mask).
    `noise`: the previous side's `FineCloud.noise` (metres). Where only the two-way residuals
    need the side and [`fits_two_way`][] says the view is fitted one-way, it is an empty side
    of the same shapes (no plane is fitted)."""
    if config.fine is None or not (config.fine.two_way or config.fine.residual == "plane_to_plane"):
        return None

    def build():
        return fine_cloud(curr.T, valid, config, planes, d)

    if config.fine.residual == "plane_to_plane" or config.fine.symmetric is True:
        return build()
    empty = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(build))
    return jax.lax.cond(fits_two_way(config.fine, noise), build, lambda: empty)


def fits_two_way(stage: FineStage, noise) -> bool | Bool[Array, ""]:
    """Whether a fine stage with two-way residuals (`FineStage.two_way`) adds them on a view
    whose previous side shows `noise` (`FineCloud.noise`, metres): always with
    `FineStage.symmetric` True; with "noisy" or "finish", where the view shows range noise
    (`EXACT_RMS` or more)."""
    return True if stage.symmetric is True else noise >= EXACT_RMS


def out_of_moved_frame(p: Float[Array, "6"], a: Float[Array, "3 K"]) -> Float[Array, "3 K"]:
    """Points of frame ν (SoA) in frame n: G(θ, φ, ψ) a + (x, y, z), the inverse of
    `_moved`. Radians and metres."""
    G = rotation(p[0], p[1], p[2])
    return jnp.stack(rotate_components(G, a[0], a[1], a[2])) + p[3:, None]


def _plane_distance(points: Float[Array, "3 S"], matched: "Matches", weight) -> Float[Array, " S"]:
    """nᵀx − o of each point against its matched plane (metres); 0 where `weight` is false.
    Written out per component (see `_residuals`)."""
    n = matched.normals
    r = n[0] * points[0] + n[1] * points[1] + n[2] * points[2] - matched.offsets
    return jnp.where(weight, r, 0.0)


EXACT_PLANAR_FRACTION = 0.7
"""Fraction of the previous points, the most planar ones, counted as faces
(`FineCloud.planar`): [`exact_surface`][] keeps only their planes, and the "hybrid" anchor
puts their planes through the neighbourhood's centroid (the others' through the point).
Noise-free, the plane of a neighbourhood across an edge or a corner misses the faces by
micrometres to millimetres, more than a noise-free fit's error; under range noise those
planes carry information the faces lack (`FineStage.planar_fraction`)."""


def exact_surface(fine: FineCloud) -> FineCloud:
    """`fine` with every plane through its own point, and only the `EXACT_PLANAR_FRACTION` most
    planar ones: the anchor without the centroid's bias on curved surfaces and across edges
    (r²/2R, tenths of a millimetre on the benchmark's cylinders and dishes), for views whose
    residuals show no range noise to average (`EXACT_RMS`)."""
    return eqx.tree_at(lambda f: (f.offsets, f.valid), fine, (fine.point_offsets, fine.planar))


EXACT_RMS = 1e-3
"""A fine-stage result whose weighted RMS residual over its most planar matches
(`FineResult.planar_rms`) is below this (metres) is polished by a
second run against [`exact_surface`][] (`estimate`): a view this clean has no noise for the
centroid anchor to average, only its curvature bias. On the realistic subset the noise-free
pairs' RMS was 0.0–0.9 mm with centroid anchors and the noisy ones' 1.5 mm and up."""


def without_range_noise(fit: FineResult) -> Bool[Array, "*batch"]:
    """Whether a fine-stage result's residuals show no range noise: its weighted RMS over its
    most planar matches (`FineResult.planar_rms`, metres) is below `EXACT_RMS`."""
    return fit.planar_rms < EXACT_RMS


def _moved(p: Float[Array, "6"], b: Float[Array, "3 S"]) -> Float[Array, "3 S"]:
    """q = G(θ, φ, ψ)ᵀ (b − (x, y, z)): points of frame n (SoA) in frame ν."""
    return jnp.stack(into_moved_frame(p, b[0], b[1], b[2]))


def _match(q: Float[Array, "3 S"], fine: FineCloud):
    """Nearest selected previous point of each q (index) and its distance, metres (inf beyond
    the neighbour search's reach). A match whose point is not planar is no inlier."""
    q = jax.lax.stop_gradient(q)  # the correspondence is held constant under differentiation
    return nearest(fine.grid, q, NEIGHBOUR_SLOTS)


class Matches(NamedTuple):
    """The plane (unit normal, offset; frame n) matched to each current point, whether its
    previous point has a plane (`FineCloud.valid`), the previous point itself, and whether it
    is among the most planar (`FineCloud.planar`)."""

    normals: Float[Array, "3 S"]
    offsets: Float[Array, " S"]
    valid: Bool[Array, " S"]
    points: Float[Array, "3 S"]
    planar: Bool[Array, " S"]


def _residuals(p, b, matched: Matches, weight):
    """Point-to-plane residuals of the current points b (frame n) at p against their matched
    previous points and normals; 0 where `weight` is false. Metres.

    The dot product is written out per component: as `jnp.sum(normals * q, axis=0)`,
    `jax.jit(jax.jacfwd(...))` returned a wrong Jacobian from 6144 points up on XLA:CPU (jax
    0.10.2; two of its columns equal, so a singular covariance and a wrong Levenberg–Marquardt
    step), while the eager Jacobian was right. `tests/test_fine.py` compares the two."""
    return _plane_distance(_moved(p, b), matched, weight)


PLANE_EPSILON = 1e-3
"""ε of the plane-to-plane residuals (`FineStage.residual`): each neighbourhood is a plane of
covariance diag(ε, 1, 1) in its normal's frame, as GICP regularises its covariances."""


def combined_planes(matched: Matches, curr: FineCloud, p: Float[Array, "6"], on) -> tuple[Matches, Float[Array, " S"]]:
    """Plane-to-plane matches at p (frame n, radians and metres): each match's plane turned to
    the mean of the previous normal and the current point's own normal (`curr.normals`, moved
    into frame ν), through the point of the previous plane nearest the previous point, and its
    weight 2ε / (1 − cos θ + 2ε), θ the angle between the two normals, ε = `PLANE_EPSILON`.

    Why: for two planar neighbourhoods of covariance diag(ε, 1, 1), GICP's weight of the
    distance along the mean normal is 1 / (1 − cos θ + 2ε) (the smallest eigenvalue of the
    sum of the two covariances, to first order); the in-plane directions, weighted about
    1 / 2, are left to the point-to-point term (`POINT_WEIGHT`). Matches whose normals agree
    count fully (weight 1 at θ = 0); across an edge, or between normals the noise tilted,
    they count less. The previous plane alone decides where the current point has no plane
    or `on` (a boolean, possibly traced) is false. Held fixed within a round, as the matches
    are."""
    G = rotation(p[0], p[1], p[2])
    m = jnp.stack(rotate_components(G.T, curr.normals[0], curr.normals[1], curr.normals[2]))
    n = matched.normals
    cos = n[0] * m[0] + n[1] * m[1] + n[2] * m[2]
    m = jnp.where(cos < 0, -m, m)
    mean = n + m
    length = jnp.sqrt(mean[0] ** 2 + mean[1] ** 2 + mean[2] ** 2)
    usable = on & curr.valid & matched.valid & (length > 0)
    normal = jnp.where(usable[None], mean / jnp.where(usable, length, 1.0)[None], n)
    height = matched.offsets - (n[0] * matched.points[0] + n[1] * matched.points[1] + n[2] * matched.points[2])
    anchor = matched.points + n * height[None]
    offset = jnp.where(usable, normal[0] * anchor[0] + normal[1] * anchor[1] + normal[2] * anchor[2], matched.offsets)
    eps = 2 * PLANE_EPSILON
    weight = jnp.where(usable, eps / (1 - jnp.abs(cos) + eps), 1.0)
    return matched._replace(normals=normal, offsets=offset), weight


def _matches(fine: FineCloud, nearest: Int[Array, " S"], dist: Float[Array, " S"], live, inlier):
    """The planes of the previous points `nearest` (indices into `fine.points`), the inlier
    mask (live current points within `inlier`, metres, `dist`, of a previous point with a
    plane) and the near mask (within `inlier` of any previous point: `FineResult.inliers`)."""
    matched = Matches(
        fine.normals[:, nearest],
        fine.offsets[nearest],
        fine.valid[nearest],
        fine.points[:, nearest],
        fine.planar[nearest],
    )
    near = live & (dist < inlier)
    return matched, near & matched.valid, near


def _correspond(p, b, live, fine: FineCloud, inlier) -> tuple[Matches, Bool[Array, " S"], Bool[Array, " S"]]:
    """The nearest previous point (and normal) of each current point at p, and the inlier and
    near masks (`_matches`)."""
    return _matches(fine, *_match(_moved(p, b), fine), live, inlier)


GRAPH_SHIFT = 0.5
"""A round matches by one step of descent on the previous points' neighbour graph
(`_neighbours.nearest_in_graph`: each current point's last match and its
`FineStage.neighbours` neighbours, 21 distances) instead of the voxel search (144 distances
and a sorted-key lookup), as long as no selected current point has moved more than this
many voxel edges (`NEIGHBOUR_VOXEL` sampling steps, so one step) since the last voxel
search: a point that moved that little has its new nearest inside its last match's
neighbourhood (≈ 2.5 steps across for 20 neighbours), and the points the search left without
a match are still beyond reach. The phases of a fit:

- approach: the first round searches the voxels; a later round descends the graph while
  the motion since the last search stays within the bound, and past it gets the voxel
  search's matches again (certified where the graph proves them and searched elsewhere,
  `CERTIFIED_BUFFER`);
- finish: from the first graph round whose step is small enough to end the fit, every round
  has the voxel search's matches (proved by the graph where it can, `CERTIFIED_BUFFER`, and
  searched elsewhere), and only such a round ends it, as when every round searched.

Measured against every round searching, from rest on realistic-benchmark pairs: noise-free
N5 the same fit (`tests/test_fine.py`); with 1 cm noise within 0.07° and 0.04 cm on the
satellite and the upper stage, with about half the searches. With the bound measured per
round instead of since the last search, a slow crawl of small rounds kept the points first
left unmatched out of the fit and ended 1° off (upper stage); with a bound of one voxel
edge, 0.5° off (docs, Findings: matching by descent on the neighbour graph). The choice is
a `lax.cond`: under `jax.vmap` with a batched choice both branches run, and a batch pays
for the voxel search in every round."""


CERTIFIED_BUFFER = 4
"""Every round after a fit's first that does not descend the graph (`GRAPH_SHIFT`: the
approach rounds past its bound and the finish rounds) matches without a voxel search
wherever it can prove the answer: one step of graph descent from each point's last match,
kept where it is certainly the nearest (`_neighbours.certified_in_graph`: the point lies
nearer to it than to anything outside its last match's neighbourhood, `FineCloud.radius`),
or, in a finish round, where the point certainly lies beyond `FineStage.inlier` of every
previous point (so it is no inlier whatever its match; an approach round searches those
too, since the graph rounds after it start from its matches). The rest, at most 1/this of
the selected current points, go to the voxel search, gathered; with more, the whole round
searches. So these rounds' matches are those the voxel search gives wherever that search
reads every point within its reach, at a fraction of its cost (measured on the realistic
benchmark's pairs near convergence: 60–98 % certified, 0–13 % beyond reach)."""


def _certified_matches(fine: FineCloud, q, live, last, q_exact, d_exact, inlier, finishing):
    """A certified round's matches ([`CERTIFIED_BUFFER`][]) of the moved current points q (SoA,
    metres): nearest index, distance, and which points got an exact match (certified or
    searched; the others are certainly beyond `inlier`). `q_exact`, `d_exact`: each point
    where it last got an exact match, and that match's distance (inf: none within the
    search's reach, so at least the voxel edge away). Only in the finish phase (`finishing`,
    a traced boolean) are points certainly beyond `inlier` left unsearched: an approach
    round's matches are where the graph rounds after it start from, so there every live
    point gets the voxel search's match."""
    index, dist, certain, bound = certified_in_graph(fine.points, fine.graph, fine.radius, last, q)
    drift = jnp.sqrt(jnp.sum((q - q_exact) ** 2, axis=0))
    beyond = jnp.maximum(jnp.minimum(d_exact, fine.grid.size) - drift, bound) >= inlier
    need = live & ~certain & ~(beyond & finishing)
    S = q.shape[1]
    room = max(S // CERTIFIED_BUFFER, 1)

    def gathered():
        (slot,) = jnp.nonzero(need, size=room, fill_value=S)
        found, far = _match(jnp.take(q, slot, axis=1, mode="clip"), fine)
        return index.at[slot].set(found, mode="drop"), dist.at[slot].set(far, mode="drop"), certain | need

    def everywhere():
        found, far = _match(q, fine)
        return found, far, jnp.ones(S, bool)

    return jax.lax.cond(jnp.sum(need) <= room, gathered, everywhere)


def _round_matches(fine: FineCloud, q, live, lasts, local, first, inlier):
    """The nearest previous point of each moved current point q (SoA, metres), its distance,
    and which points got an exact match: in a fit's `first` round (a traced boolean: no last
    match to start from) by the voxel search; where `local` (a traced boolean), by a step of
    graph descent from the last matches (`GRAPH_SHIFT`; inf where the last voxel search had
    not reached the point, `d_exact` inf; none exact); in every other round, by
    [`_certified_matches`][] (the voxel search's matches, certified where the graph proves
    them)."""
    q = jax.lax.stop_gradient(q)
    last, q_exact, d_exact, finishing = lasts

    def search():
        index, dist = _match(q, fine)
        return index, dist, jnp.ones(q.shape[1], bool)

    def graph():
        index, dist = nearest_in_graph(fine.points, fine.graph, last, q)
        return index, jnp.where(jnp.isfinite(d_exact), dist, jnp.inf), jnp.zeros(q.shape[1], bool)

    def certified():
        return _certified_matches(fine, q, live, last, q_exact, d_exact, inlier, finishing)

    mode = jnp.where(first, 0, jnp.where(local, 1, 2))
    return jax.lax.switch(mode, (search, graph, certified))


def median_magnitude(r: Float[Array, " S"], keep: Bool[Array, " S"]) -> Float[Array, ""]:
    """The median of |r| over the entries `keep` (NaN where none is kept): the value of
    `jnp.nanmedian(jnp.where(keep, jnp.abs(r), jnp.nan))`, bit for bit, without its sort.

    A magnitude is a non-negative float, whose bit pattern, read as an integer, grows with
    the value; the k-th smallest kept magnitude is found exactly by bisection on that integer
    (one count of the entries at or below a trial pattern per bit). The two middle order
    statistics then combine as `nanmedian` combines them, (low + high) · 0.5. A full sort of
    4096 residuals in every fine-stage round was about a tenth of the public call on the
    2-core CPU (docs, Findings: the voxel search's constant cost)."""
    itype = jnp.int64 if r.dtype.itemsize == 8 else jnp.int32
    keep = keep & ~jnp.isnan(r)  # as nanmedian, which drops the NaN it is given
    bits = jnp.where(keep, jax.lax.bitcast_convert_type(jnp.abs(r), itype), jnp.iinfo(itype).max)
    n = jnp.sum(keep)
    ranks = jnp.stack([(n - 1) // 2, n // 2])  # the floor and ceiling of (n − 1) / 2

    def halve(_, bounds):
        # Invariant: fewer than rank + 1 entries lie at or below lo; at least that many at hi.
        lo, hi = bounds
        mid = lo + (hi - lo) // 2
        enough = jnp.sum(bits[None, :] <= mid[:, None], axis=1) >= ranks + 1
        return jnp.where(enough, lo, mid), jnp.where(enough, mid, hi)

    inf_bits = jax.lax.bitcast_convert_type(jnp.asarray(jnp.inf, r.dtype), itype)
    start = (jnp.full(2, -1, itype), jnp.full(2, inf_bits, itype))
    _, found = jax.lax.fori_loop(0, 8 * r.dtype.itemsize, halve, start)
    low, high = jax.lax.bitcast_convert_type(found, r.dtype)
    return jnp.where(n > 0, (low + high) * jnp.asarray(0.5, r.dtype), jnp.nan)


def _robust_weights(r: Float[Array, " S"], inlier: Bool[Array, " S"]) -> Float[Array, " S"]:
    """Cauchy IRLS weights of residuals r (metres) for one round (see `ROBUST_SCALE`); 0 for
    points that are no inliers."""
    spread = 1.4826 * median_magnitude(r, inlier)
    c = jnp.maximum(ROBUST_SCALE * jnp.where(jnp.isfinite(spread), spread, 0.0), ROBUST_FLOOR)
    return jnp.where(inlier, 1 / (1 + (r / c) ** 2), 0.0)


def _step_in_deviations(y, step, weighted_residuals, r, w) -> Float[Array, ""]:
    """‖J Δp‖ / σ̂: the length of a step in standard deviations of the least-squares result
    (see `NOISE_STEP`), with J the Jacobian of `weighted_residuals` at y (one JVP) and σ̂ the
    weighted RMS of the residuals r with weights w, at least `SIGMA_FLOOR`."""
    _, change = jax.jvp(weighted_residuals, (y,), (step,))
    sigma = jnp.maximum(_weighted_rms(r, w), SIGMA_FLOOR)
    return jnp.sqrt(jnp.sum(change**2)) / sigma


def _weighted_rms(r: Float[Array, " S"], w: Float[Array, " S"]) -> Float[Array, ""]:
    """√(Σ w r² / Σ w), metres (0 when every weight is 0)."""
    return jnp.sqrt(jnp.sum(w * r**2) / jnp.maximum(jnp.sum(w), jnp.finfo(r.dtype).tiny))


def select_current(
    problem, config: Config, p: Float[Array, "6"], smooth=True
) -> tuple[Float[Array, "3 S"], Bool[Array, " S"]]:
    """The current points (frame n, SoA) within `FineStage.curr_slab`·d of a cutting plane of frame
    ν(p), thinned evenly to `FineStage.points`, and their mask. Where the problem holds a
    smoothed current side (`Problem.fine_curr`, the whole surface), its points: the smoothed
    ones where `smooth` (a boolean, possibly traced), else the raw ones."""
    side = problem.fine_curr
    if side is not None:
        return jnp.where(smooth, side.smoothed, side.points), side.live
    q = _moved(p, problem.curr)
    near = problem.curr_valid & (slab_distance(q, problem.planes, problem.d) <= config.fine.curr_slab * problem.d)
    idx, live = spread_subset(near, config.fine.points)
    return problem.curr[:, idx], live


class FitMatches(NamedTuple):
    """The matches of a fine-stage result p that its covariance and its holds read
    ([`fit_matches`][]): the raw current points `points` (frame n, SoA, `(3, S)`), their
    nearest previous points and planes `matched` and which are inliers `weight`."""

    points: Float[Array, "3 S"]
    matched: "Matches"
    weight: Bool[Array, " S"]


def fit_matches(problem, config: Config, p: Float[Array, "6"]) -> FitMatches:
    """The raw current points (`select_current` without smoothing) matched to the previous
    side at p (frame n): one voxel search, shared by [`fine_least_squares`][] and
    [`face_holds`][]. The raw points, not the smoothed ones: smoothing correlates neighbouring
    residuals and shrinks σ̂ below the range noise, which `COVARIANCE_SCALE` was calibrated on."""
    p = jnp.asarray(p, problem.d.dtype)
    b, live = select_current(problem, config, p, smooth=False)
    matched, weight, _ = _correspond(p, b, live, problem.fine, config.fine.inlier)
    return FitMatches(b, matched, weight)


def fine_least_squares(
    problem, config: Config, p: Float[Array, "6"], matches: FitMatches | None = None
) -> tuple[Float[Array, ""], Float[Array, "6 6"]]:
    """The two factors of the least-squares covariance of a fine-stage result p (frame n):
    σ̂ (metres), the residual scale, and (JᵀJ)⁻¹ (the covariance of p, radians and metres, per
    square metre of residual variance), with J the Jacobian of the matched point-to-plane residuals at p (the
    Gauss–Newton Hessian of the fine objective) and σ̂² = Σ r² / (n − 6) over the n inliers.
    σ̂ is at least `SIGMA_FLOOR`, so that a noise-free view gives a positive definite
    covariance. The residuals are those of the raw current points (`CurrentSide.points`),
    also where the fit used the smoothed ones: the covariance of a fit to smoothed points is
    at most this one. `matches`: [`fit_matches`][] at p, where the caller has them."""
    p = jnp.asarray(p, problem.d.dtype)
    b, matched, weight = fit_matches(problem, config, p) if matches is None else matches
    J = jax.jacfwd(_residuals)(p, b, matched, weight)
    r = _residuals(p, b, matched, weight)
    sigma2 = jnp.maximum(jnp.sum(r**2) / jnp.maximum(jnp.sum(weight) - 6, 1), SIGMA_FLOOR**2)
    unit = jnp.linalg.inv(J.T @ J)
    return jnp.sqrt(sigma2), (unit + unit.T) / 2


def fine_covariance(problem, config: Config, p: Float[Array, "6"]) -> Float[Array, "6 6"]:
    """Least-squares covariance of a fine-stage result p (radians and metres, frame n):
    Σ = σ̂² (JᵀJ)⁻¹, the product of [`fine_least_squares`][]'s two factors. Assumes
    independent residuals; `experiments/nees.py` and `experiments/nees_realistic.py` measure
    how far that holds (`FineStage.covariance_scale`, `FineStage.covariance_noise`)."""
    sigma, unit = fine_least_squares(problem, config, p)
    return sigma**2 * unit


class RotationHold(NamedTuple):
    """How firmly the matched faces hold the rotation of a fit (`jaxpose._fine.face_holds`).

    - `lever`: metres, the root mean square distance along their planes' normals that the
      current points matched to faces move per radian of the weakest turn, with the
      translation that best undoes it (0 where no point is matched to a face).
    - `axis`: `(3,)` the weakest turn's unit axis (sign arbitrary): frame n from
      `face_holds`, the camera frame c in `Estimate.hold`; zero where no point is matched
      to a face.
    """

    lever: Float[Array, ""]
    axis: Float[Array, "3"]


class SlideHold(NamedTuple):
    """How firmly the matched faces hold the translation of a fit (`jaxpose._fine.face_holds`).

    - `grip`: dimensionless, 0–1: the root mean square component along the weakest
      translation's direction of the normals of the faces the current points are matched to
      (0: a slide that way moves no such point off its plane, as along the edge where two
      flat faces meet; 0 where no point is matched to a face).
    - `direction`: `(3,)` the weakest translation's unit direction (sign arbitrary): frame n
      from `face_holds`, the camera frame c in `Estimate.slide`; zero where no point is
      matched to a face.
    """

    grip: Float[Array, ""]
    direction: Float[Array, "3"]


def face_holds(
    problem, config: Config, p: Float[Array, "6"], matches: FitMatches | None = None
) -> tuple[RotationHold, SlideHold]:
    """The turn and the translation that the matched faces of a fine-stage result p (frame n,
    radians and metres) hold least firmly, and how firmly ([`RotationHold`][],
    [`SlideHold`][]).

    A small turn δ (rotation vector) of a matched current point q, with a translation τ,
    changes its point-to-plane residual by δ·((q − c) × n) + τ·n, n its plane's normal. Over
    the inliers of [`fine_covariance`][] matched to a face (`FineCloud.planar`: the most
    planar previous neighbourhoods), the mean outer product of ((q − c) × n, n) is a 6 × 6
    information per point.

    - The turn: with the translation eliminated (Schur complement; c drops out) the smallest
      eigenvalue of its rotation block is the squared `lever` and its eigenvector the `axis`.
    - The translation: the smallest eigenvalue of its translation block, the mean n nᵀ, is
      the squared `grip` and its eigenvector the `direction`. Where the faces leave a
      direction free (two flat faces: along their common edge; a bare cylinder: along its
      axis) only the view's outline holds the fit there, through the fine stage's
      point-to-point term, and on noise-free views the least-squares covariance still
      promises micrometres. Range noise scatters the fitted normals and raises the grip
      above its noise-free value.

    Faces only: the plane of least scatter across an edge or a corner, which the fit uses
    too, tilts with the edge's sampling, and along a single face's outline it made a turn
    about the face's normal look held. A turn the faces do not hold is left to the outline
    and to where the fit started (a single flat face seen head-on: the turn about its normal;
    a bare cylinder: the turn about its axis). Geometric stability in the sense of Gelfand et
    al. (2003), for the fit's own matches ([`fit_matches`][] at p, or `matches` where the
    caller has them)."""
    p = jnp.asarray(p, problem.d.dtype)
    b, matched, weight = fit_matches(problem, config, p) if matches is None else matches
    q, n = _moved(p, b), matched.normals
    w = (weight & matched.planar).astype(q.dtype)
    count = jnp.maximum(jnp.sum(w), 1.0)
    centre = jnp.sum(q * w[None], axis=1, keepdims=True) / count
    rows = jnp.concatenate([jnp.cross(q - centre, n, axis=0), n])  # (6, S)
    H = (rows * w[None]) @ rows.T / count
    Hrr, Hrt, Htt = H[:3, :3], H[:3, 3:], H[3:, 3:]
    # A ridge keeps the elimination finite where the planes leave a translation free (one face).
    ridge = 1e-6 * jnp.trace(Htt) + jnp.finfo(q.dtype).tiny
    S = Hrr - Hrt @ jnp.linalg.solve(Htt + ridge * jnp.eye(3, dtype=q.dtype), Hrt.T)
    values, vectors = jnp.linalg.eigh((S + S.T) / 2)
    shift_values, shift_vectors = jnp.linalg.eigh((Htt + Htt.T) / 2)
    matched_any = jnp.sum(w) > 0
    lever = jnp.where(matched_any, jnp.sqrt(jnp.maximum(values[0], 0.0)), 0.0)
    grip = jnp.where(matched_any, jnp.sqrt(jnp.maximum(shift_values[0], 0.0)), 0.0)
    return (
        RotationHold(lever, jnp.where(matched_any, vectors[:, 0], 0.0)),
        SlideHold(grip, jnp.where(matched_any, shift_vectors[:, 0], 0.0)),
    )


def least_squares_solver(tol: float) -> optx.GaussNewton:
    """optimistix's Gauss–Newton with rtol = atol = `tol`, solving each step by Cholesky on the
    normal equations JᵀJ δ = −Jᵀr (lineax `Normal(Cholesky())`).

    With the matches of a round fixed, the weighted point-to-plane problem is nearly linear in
    p, and the point-to-point term (`POINT_WEIGHT`) keeps JᵀJ positive definite wherever a
    round has three non-collinear inliers, so a plain Gauss–Newton step needs no damping; a
    round whose step comes out non-finite (a singular JᵀJ: one or two inliers) leaves p where
    it was (`fine_refine`). The
    Jacobian is tall and thin (thousands of residuals, 6 unknowns), so forming the 6 × 6 system
    costs less than a QR of J. On the realistic benchmark's 28 pairs of `make_cases(1)` the
    median call took 328 ms with optimistix's Levenberg–Marquardt and QR, 198 ms with
    Levenberg–Marquardt and this Cholesky, and 173 ms with this solver, with the same pairs found
    and no false success (docs, Findings: cheaper stages of the public call)."""
    return optx.GaussNewton(rtol=tol, atol=tol, linear_solver=lx.Normal(lx.Cholesky()))


BACK_POINTS = 1024
"""Previous points (with a plane, thinned evenly) that the two-way half of a round matches
against the current side (`back_matches`, `back_residuals`). Every previous point (4096)
made the call 1.7–2.3 times as long as the one-way fit's on the realistic benchmark, these
1.1–1.25 times, with mixed changes in accuracy (docs, Findings: two-way residuals); both
measured when the back matches searched the voxels in every round, as they now do only
where the forward matches would (`GRAPH_SHIFT`)."""


def back_points(fine: FineCloud) -> tuple[Float[Array, "3 B"], Bool[Array, " B"]]:
    """`BACK_POINTS` of the previous side's points with a plane (`fine.valid`), thinned evenly
    (SoA, frame n), and their mask: the queries of [`back_residuals`][], chosen once a fit."""
    idx, live = spread_subset(fine.valid, min(BACK_POINTS, fine.valid.shape[0]))
    return fine.points[:, idx], live


def point_terms(moved: Float[Array, "3 S"], matched: Float[Array, "3 S"], root_w: Float[Array, " S"]):
    """The weighted point-to-point residuals (`POINT_WEIGHT`, metres) of the moved points
    against their matched points (SoA), as three (S,) arrays, one per axis.

    Three leaves rather than one (3, S) array, for the Gauss–Newton step's JᵀJ: each leaf's
    Jacobian block comes out as (6, S), as the plane residuals' does, and XLA:CPU forms its
    6 × 6 product directly. A single (3, S) leaf's block is copied into (6, 3S) and (3S, 6)
    layouts first, and its product takes about 12 times as long as the plane block's for 3
    times the rows (`experiments/call_profile.py`). The sum of squares is the same."""
    return tuple(POINT_WEIGHT * root_w * (moved[k] - matched[k]) for k in range(3))


def back_matches(back: FineCloud, moved: Float[Array, "3 B"], live, lasts, local, first, inlier):
    """The two-way half of a round's matches (`FineStage.symmetric`): the previous points
    ([`back_points`][]) where `live`, at `moved` (their places in frame n of the current cloud
    at the round's p, `out_of_moved_frame`), matched to their nearest current points (`back`)
    as the forward matches are ([`_round_matches`][]: a voxel search in a fit's `first` round,
    a step of graph descent where `local`, certified graph matches otherwise; `lasts` = (last
    match, where each point last got an exact match, its distance, the finish phase)).
    Returns the index, the distance (metres) and which matches are exact. With no live query
    (a one-way run of the "noisy" default on a noise-free view) nothing is searched."""
    unmatched = (
        jnp.zeros(live.shape, jnp.int32),
        jnp.full(live.shape, jnp.inf, moved.dtype),
        jnp.zeros(live.shape, bool),
    )
    return jax.lax.cond(
        jnp.any(live), lambda: _round_matches(back, moved, live, lasts, local, first, inlier), lambda: unmatched
    )


def back_residuals(back: FineCloud, points: Float[Array, "3 B"], moved, index, dist, live, inlier):
    """The two-way residuals of a round: the previous points `points` where `live`, at `moved`
    (their places in frame n of the current cloud at the round's start) with their matches
    `index`, `dist` ([`back_matches`][]); the matches within `inlier` (metres) of a current point
    with a plane get Cauchy weights from their distances to its plane (`_robust_weights`).
    Returns a function of p giving the weighted plane distances and, like the forward
    residuals, the `POINT_WEIGHT` point-to-point ones (metres)."""
    matched, weight, _ = _matches(back, index, dist, live, inlier)
    root_w = jnp.sqrt(_robust_weights(_plane_distance(moved, matched, weight), weight))

    def residuals(p_):
        a = out_of_moved_frame(p_, points)
        plane = root_w * _plane_distance(a, matched, weight)
        return plane, *point_terms(a, matched.points, root_w)

    return residuals


def back_round(
    back: FineCloud, points: Float[Array, "3 B"], live, p: Float[Array, "6"], lasts, rounds, finishing, inlier
):
    """One round's two-way half: the back matches of the previous points `points` where `live`
    at p ([`back_matches`][]), in the phase the forward matches are in (`finishing`; a voxel
    search in round 0), descending the graph while these points have moved less than
    `GRAPH_SHIFT` of the current side's voxel edges since their last exact match. `lasts` =
    (last match, where each point last got an exact match, its distance). Returns the round's
    residual function ([`back_residuals`][]), whether it matched by graph descent (then the
    round cannot end the fit), and the updated `lasts`."""
    _, exact_at, d_exact = lasts
    moved = jax.lax.stop_gradient(out_of_moved_frame(p, points))
    shift = jnp.max(jnp.where(live, jnp.sum((moved - exact_at) ** 2, axis=0), 0.0))
    reach = GRAPH_SHIFT * back.grid.size
    local = jnp.any(live) & (rounds > 0) & (shift <= reach**2) & ~finishing
    index, dist, exact = back_matches(back, moved, live, (*lasts, finishing), local, rounds == 0, inlier)
    terms = back_residuals(back, points, moved, index, dist, live, inlier)
    lasts = (index, jnp.where(exact[None], moved, exact_at), jnp.where(exact, dist, d_exact))
    return terms, local, lasts


def fine_refine(
    problem,
    config: Config,
    start: Float[Array, "6"],
    fine: FineCloud | None = None,
    active=True,
    smooth=True,
    two_way=True,
    combine=True,
    joins: Float[Array, "k 6"] | None = None,
) -> FineResult:
    """Minimise the point-to-plane residuals of the selected current points from `start` (frame n).
    See the module docstring. Pure and jittable.

    Rounds of: match each current point to its nearest previous point at the current p, then
    solve the least-squares problem with those correspondences fixed (optimistix Gauss–Newton,
    `least_squares_solver`). A nearest-neighbour search costs S·K distances and the fixed-match
    solve only S residuals, so matching once per round rather than once per solver evaluation
    made the stage about 6× cheaper (370 → 65 ms on N5 variant 2); matching by graph descent
    where the points moved little since the last voxel search (`GRAPH_SHIFT`) reads 21
    candidates per point instead of 144 in most later rounds; the two-way back matches
    ([`back_matches`][]) do the same on the current side's graph, with their own bound, and
    took the noisy calls' median from 148–184 ms to 139–160 ms on four realistic draws (docs,
    Findings: back matches by graph descent). Stops when a round whose matches (both ways)
    are exact moves p by less than `ROUND_TOL` or than `NOISE_STEP` standard deviations, or after
    `FineStage.rounds` rounds; `converged` says which. `fine` replaces the problem's previous
    side (e.g. [`exact_surface`][]). With `active` false (a boolean, possibly traced) no round
    runs: the result is `start`, not converged, with no inliers, so that a caller can compile
    one run and skip it where it is not needed (`jaxpose._estimate.fine_passes`). `smooth`
    (a boolean, possibly traced): fit the smoothed current points where the problem has them
    ([`CurrentSide`][]), else the raw ones (the noise-free polish). `two_way` (a boolean,
    possibly traced): where the problem holds the current side's planes (`fine_back`,
    `FineStage.symmetric`), also fit the previous points to them ([`back_residuals`][]).
    `combine` (a boolean, possibly traced): with `FineStage.residual` "plane_to_plane", fit
    plane-to-plane ([`combined_planes`][]); else, or where false (the noise-free polish),
    point-to-plane. `joins`: p (frame n) of earlier converged fits, NaN rows where none; a
    round that ends within `JOIN_RADIUS` of one stops the fit, and `FineResult.joined` says
    which (the caller takes that fit's result, `jaxpose._estimate.fine_passes`).
    """
    dtype = problem.d.dtype
    start = jnp.asarray(start, dtype)
    fine = problem.fine if fine is None else fine
    inlier = jnp.asarray(config.fine.inlier, dtype)
    b, live = select_current(problem, config, start, smooth)
    # The raw points measure the noise (the stop's σ̂, the result's RMS): smoothed residuals
    # are correlated and smaller than the range noise (`CurrentSide`). Without a smoothed side
    # they are the fitted points themselves.
    smoothing = problem.fine_curr is not None
    raw = problem.fine_curr.points if smoothing else b
    scale = jnp.asarray(PARAMETER_SCALE, dtype)
    solver = least_squares_solver(config.fine.tol)

    reach = GRAPH_SHIFT * fine.grid.size
    back = problem.fine_back if config.fine.two_way else None
    own_planes = problem.fine_back if config.fine.residual == "plane_to_plane" else None
    if back is not None:
        queries, queried = back_points(fine)
        queried = queried & two_way & fits_two_way(config.fine, fine.noise)
    else:
        queries, queried = jnp.zeros((3, 0), dtype), jnp.zeros(0, bool)

    def one_round(state):
        # last: each point's last match; q_exact, d_exact: where each point last got an exact
        # match (a voxel search, or a certified round's) and its distance (inf: the search found
        # none in reach); finishing: the fit's finish phase.
        y, _, rounds, steps, _, lasts, back_lasts, _ = state
        last, q_exact, d_exact, finishing = lasts
        q = _moved(y * scale, b)
        shift = jnp.max(jnp.where(live, jnp.sum((q - q_exact) ** 2, axis=0), 0.0))
        local = (rounds > 0) & (shift <= reach**2) & ~finishing
        index, dist, exact = _round_matches(fine, q, live, lasts, local, rounds == 0, inlier)
        back_terms, back_local = None, jnp.asarray(False)
        if back is not None:
            back_terms, back_local, back_lasts = back_round(
                back, queries, queried, y * scale, back_lasts, rounds, finishing, inlier
            )
        matched, weight, near = _matches(fine, index, dist, live, inlier)
        agreement = 1.0
        if own_planes is not None:
            matched, agreement = combined_planes(matched, own_planes, y * scale, combine)
        r0 = _residuals(y * scale, b, matched, weight)
        w0 = _robust_weights(r0, weight) * agreement
        root_w = jnp.sqrt(w0)

        def fn(y_, _):
            p_ = y_ * scale
            plane = root_w * _residuals(p_, b, matched, weight)
            point = point_terms(_moved(p_, b), matched.points, root_w)
            terms = (plane, *point) if back_terms is None else (plane, *point, *back_terms(p_))
            return tuple(t / RESIDUAL_UNIT for t in terms)

        sol = optx.least_squares(fn, solver, y, None, max_steps=config.fine.steps, throw=False)
        step = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value - y, 0.0)
        moved = jnp.max(jnp.abs(step))
        within_noise = _step_in_deviations(
            y,
            step,
            lambda y_: root_w * _residuals(y_ * scale, b, matched, weight),
            _residuals(y * scale, raw, matched, weight) if smoothing else r0,
            w0,
        )
        small = (moved <= ROUND_TOL) | (within_noise <= NOISE_STEP)
        # Only a round whose matches are exact (a voxel search, or a certified round's
        # `CERTIFIED_BUFFER`), the back matches' included, ends the fit (`GRAPH_SHIFT`).
        graph_round = local | back_local
        settled = small & ~graph_round
        q_exact = jnp.where(exact[None], q, q_exact)
        d_exact = jnp.where(exact, dist, d_exact)
        lasts = (index, q_exact, d_exact, finishing | (small & graph_round))
        steps = steps + sol.stats["num_steps"]
        joined = joined_fit(y + step, joins)
        return y + step, settled, rounds + 1, steps, (matched, weight, near), lasts, back_lasts, joined

    def more(state):
        _, settled, rounds, _, _, _, _, joined = state
        return active & ~settled & (rounds < config.fine.rounds) & (joined < 0)

    # Placeholder matches, of the right structure: an active run replaces them in its first round;
    # an inactive one keeps them, with weight 0 everywhere.
    shapes = jax.eval_shape(lambda: _correspond(start, b, live, fine, inlier))
    unmatched = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
    S = b.shape[1]
    lasts = (jnp.zeros(S, jnp.int32), jnp.zeros_like(b), jnp.full(S, jnp.inf, dtype), jnp.asarray(False))
    B = queries.shape[1]
    back_lasts = (jnp.zeros(B, jnp.int32), jnp.zeros_like(queries), jnp.full(B, jnp.inf, dtype))
    joins = jnp.zeros((0, 6), dtype) if joins is None else jnp.asarray(joins, dtype) / scale[None]
    no_join = jnp.asarray(-1, jnp.int32)
    state = (start / scale, jnp.asarray(False), jnp.asarray(0), jnp.asarray(0), unmatched, lasts, back_lasts, no_join)
    y, settled, _, steps, (matched, weight, near), _, _, joined = jax.lax.while_loop(more, one_round, state)
    p = y * scale
    # The inlier fraction and RMS use the last round's matches (made where that round started,
    # within ROUND_TOL of p when converged) rather than a fresh nearest-neighbour search at p,
    # which would cost as much as a round's matching.
    r = _residuals(p, raw, matched, weight)
    w = _robust_weights(r, weight)
    n_in, used = jnp.sum(near), jnp.sum(live)
    return FineResult(
        params=p,
        converged=settled,
        steps=jnp.asarray(steps, jnp.int32),
        inliers=jnp.where(used > 0, n_in / jnp.maximum(used, 1), 0.0),
        rms=_weighted_rms(r, w),
        planar_rms=_weighted_rms(r, w * matched.planar),
        used=used.astype(jnp.int32),
        conflict=jnp.full((), jnp.nan, dtype),
        joined=joined,
    )


def joined_fit(y: Float[Array, "6"], joins: Float[Array, "k 6"]) -> Int[Array, ""]:
    """The first row of `joins` within `JOIN_RADIUS` of y in every parameter (both in the
    solver's units, `PARAMETER_SCALE`), −1 where none is (NaN rows never are)."""
    if joins.shape[0] == 0:
        return jnp.asarray(-1, jnp.int32)
    near = jnp.all(jnp.abs(joins - y[None]) <= JOIN_RADIUS, axis=1)
    return jnp.where(jnp.any(near), jnp.argmax(near), -1).astype(jnp.int32)


__all__ = [
    "CurrentSide",
    "SurfaceProblem",
    "current_side",
    "back_side",
    "back_matches",
    "back_round",
    "back_residuals",
    "combined_planes",
    "FineCloud",
    "FineResult",
    "fine_cloud",
    "view_noise",
    "fits_two_way",
    "smallest_eigen",
    "fine_covariance",
    "FitMatches",
    "fit_matches",
    "fine_least_squares",
    "RotationHold",
    "SlideHold",
    "face_holds",
    "fine_refine",
    "median_magnitude",
    "exact_surface",
    "without_range_noise",
    "select_current",
    "spread_subset",
]
