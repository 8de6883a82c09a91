"""Configuration of the method: one object per concern, gathered in a `Config`.

The sections follow the data flow: [`Patterns`][jaxpose.Patterns] (how a cloud becomes cell
patterns), [`Capacities`][jaxpose.Capacities] (the static array sizes, sized from the data
when left at None), [`GlobalSearch`][jaxpose.GlobalSearch] (the evosax CMA-ES over the
search box), [`Refine`][jaxpose.Refine] (an optimistix minimiser on the soft objective),
[`FineStage`][jaxpose.FineStage] (point-to-plane least squares),
[`Thresholds`][jaxpose.Thresholds] (what counts as a result, what counts as input) and
[`RotationSearch`][jaxpose.RotationSearch] (capture over the whole rotation group, in place of
the box search). A stage set to None does not run. Lengths in metres, angles in radians.

Presets are named constructors that differ from the default: [`Config.paper`][jaxpose.Config.paper],
[`Config.fast`][jaxpose.Config.fast], [`Config.wide`][jaxpose.Config.wide],
[`Config.capture`][jaxpose.Config.capture] and [`Config.tracking`][jaxpose.Config.tracking].
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Literal

import equinox as eqx
import optimistix as optx
from jaxtyping import ArrayLike, Float

Scalar = Float[ArrayLike, ""]
"""A setting that is a number: a Python float, or a 0-d array (traced under `jax.vmap` over
configs)."""


def _check_range(owner: str, name: str, value, lo: float, hi: float, closed_low: bool = False) -> None:
    if not isinstance(value, int | float):
        return  # an array (possibly traced) is not inspected here
    ok = (lo <= value <= hi) if closed_low else (lo < value <= hi)
    if not ok:
        bracket = "[" if closed_low else "("
        raise ValueError(f"{owner}.{name} must be in {bracket}{lo:g}, {hi:g}], got {value!r}.")


class Patterns(eqx.Module):
    """How a cloud becomes cell patterns (DECISIONS.md "Patterns and grid"), and the soft
    objective's kernels.

    - `d`: selection half-width and cell size, metres (paper: 0.026); with `cell_steps` > 0 the
      smallest cell, the one a pair uses being the larger of `d` and `cell_steps` sampling
      steps of its previous cloud. `Problem.d` holds the cell used.
    - `extension`: grid extension on each side as a fraction of the previous pattern's
      extent in cells (paper: 0.2).
    - `slices`: K parallel slices per axis, offsets (k − (K−1)/2)·2d, k = 0…K−1 (static;
      K = 1 is the paper's three planes).
    - `bin_width`: width w of the soft cell kernel, in cells, 0 < w ≤ 1 (→ 0: hard cells).
    - `select_width`: width of the soft selection edge, as a fraction of d (→ 0: hard slab).
    - `cell_steps`: the cell is at least this many sampling steps of the previous cloud (its
      median nearest-neighbour distance, `jaxpose._neighbours.voxel_spacing`), computed from
      the data inside the build, so also under `jax.jit`; 0 (the default) keeps `d` whatever
      the data. Why it exists: a ToF camera's points thin out with range (0.36 % of the range
      apart for the CamCube's 204 pixels over 40°: 2.3 cm at 6.5 m, 5.4 cm at 15 m), and cells
      smaller than the spacing break a face's pattern into isolated cells; targets 6–11 m
      across seen from 8–17 m then scored below `Thresholds.min_score` at the true motion and
      were refused (10 of 32 such pairs found but refused; none at 1.5). Why it is off by
      default: within the realistic benchmark's envelope (targets up to 4 m, 2–6.5 m away) 1.5
      steps found no more pairs and added false successes at σ 2 cm (2 of 56 on the committed
      draw, where the fixed cell has none: two satellite views 1.4° and 6.6° off that the
      low-score check refused with 2.6 cm cells passed it). For large, far targets set 1.5
      (docs, Findings: a cell that follows the sampling step).
    """

    d: Scalar = 0.026
    extension: Scalar = 0.2
    slices: int = eqx.field(static=True, default=1)
    bin_width: Scalar = 1.0
    select_width: Scalar = 0.5
    cell_steps: Scalar = 0.0

    def __check_init__(self):
        _check_range("Patterns", "d", self.d, 0.0, math.inf)
        _check_range("Patterns", "extension", self.extension, 0.0, math.inf, closed_low=True)
        _check_range("Patterns", "bin_width", self.bin_width, 0.0, 1.0)
        _check_range("Patterns", "select_width", self.select_width, 0.0, math.inf)
        _check_range("Patterns", "cell_steps", self.cell_steps, 0.0, math.inf, closed_low=True)
        if self.slices < 1:
            raise ValueError(f"Patterns.slices must be ≥ 1, got {self.slices!r}.")

    @property
    def num_planes(self) -> int:
        return 3 * self.slices

    def planes(self) -> tuple[tuple[int, float], ...]:
        """(normal axis j, offset in units of d) of every cutting plane, plane 1 first."""
        K = self.slices
        return tuple((j, 2.0 * (k - (K - 1) / 2)) for j in range(3) for k in range(K))


class Capacities(eqx.Module):
    """The static array sizes of a problem. `None`, the default for each, sizes it from the
    clouds at the Python boundary (`sized_config`: the counts and the previous patterns,
    rounded up to a few buckets so that a stream of frames reuses one compiled program).
    Under `jax.jit` a capacity left at None becomes the cloud's row count for the points and
    `JIT_GRID_CELLS` / `JIT_MAX_CELLS` for the patterns; size a config for jitted code with
    [`Config.sized_for`][jaxpose.Config.sized_for] instead. A pattern or cloud that overflows
    a capacity under jit is reported in the problem's status, never silently used.

    - `grid_cells`: capacity C of each plane's grid along each axis.
    - `max_points`: the current cloud's valid points; fewer slots score faster.
    - `max_prev_points`: the previous cloud's valid points. The previous points are compacted
      to it once; passes over them are then shorter than over the whole frame.
    - `max_cells`: the filled cells of one previous pattern.
    """

    grid_cells: int | None = eqx.field(static=True, default=None)
    max_points: int | None = eqx.field(static=True, default=None)
    max_prev_points: int | None = eqx.field(static=True, default=None)
    max_cells: int | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        for name in ("grid_cells", "max_points", "max_prev_points", "max_cells"):
            value = getattr(self, name)
            if value is not None and value < 3:
                raise ValueError(f"Capacities.{name} must be ≥ 3 or None, got {value!r}.")

    def filled(self, **sizes: int) -> Capacities:
        """These capacities with each one left at None set from `sizes`; set ones are kept."""
        return dataclasses.replace(self, **{k: v for k, v in sizes.items() if getattr(self, k) is None})


class GlobalSearch(eqx.Module):
    """The global stage: evosax's CMA-ES over a box around no motion, on a coarse problem.

    - `objective`: "hard" (the paper's) or "soft", what CMA-ES maximises (static).
    - `coarse_factor`: the search scores a second, coarse problem built with cells of
      `coarse_factor`·d (selection half-width too) from `coarse_points` current points
      thinned evenly (static; 1 = search on the full problem, as the paper). An
      evaluation's work scales with the current points scored (≈ 4 800 on the paper's N5
      frames against 512) and the grid (3 × 130² cells against 3 × 47²), and the coarse
      problem's wider cells widen each basin, so a smaller CMA-ES finds it. The refine and
      the fine stage then work on the full problem.
    - `coarse_points`: current points of the coarse problem (static).
    - `population`, `generations`: CMA-ES size (static).
    - `angle_box`, `shift_box`: half-widths of the search box for each angle (radians) and
      each translation component (metres); paper: 20° and 0.10 m.
    - `recentre`: how many more searches may run, each centred on the previous best, while
      that best lies at the edge of its box (static; 0 = one search, as the paper). The
      result is reported as at the box edge if the last search still ends there. Under
      `jax.vmap` a batch runs as many searches as its neediest pair (one `lax.while_loop`).
    - `restarts`: how many more independent searches (each with its own re-centring) may run
      while the best score is below `restart_below`; the best one is kept (static).
    - `restart_below`: the objective's value (0–1) at or above which a search is trusted and
      no restart runs.
    """

    objective: Literal["hard", "soft"] = eqx.field(static=True, default="soft")
    coarse_factor: int = eqx.field(static=True, default=3)
    coarse_points: int = eqx.field(static=True, default=512)
    population: int = eqx.field(static=True, default=16)
    generations: int = eqx.field(static=True, default=16)
    angle_box: Scalar = math.radians(20.0)
    shift_box: Scalar = 0.10
    recentre: int = eqx.field(static=True, default=2)
    restarts: int = eqx.field(static=True, default=0)
    restart_below: Scalar = 0.8

    def __check_init__(self):
        if self.objective not in ("hard", "soft"):
            raise ValueError(f"GlobalSearch.objective must be 'hard' or 'soft', got {self.objective!r}.")
        if self.coarse_factor < 1 or self.coarse_points < 10:
            raise ValueError(
                f"GlobalSearch.coarse_factor must be ≥ 1 and coarse_points ≥ 10, "
                f"got {self.coarse_factor!r}, {self.coarse_points!r}."
            )
        if self.population < 2 or self.generations < 1:
            raise ValueError(
                f"GlobalSearch needs population ≥ 2 and generations ≥ 1, got {self.population!r}, {self.generations!r}."
            )
        if self.recentre < 0 or self.restarts < 0:
            raise ValueError(
                f"GlobalSearch.recentre and restarts must be ≥ 0, got {self.recentre!r}, {self.restarts!r}."
            )
        _check_range("GlobalSearch", "angle_box", self.angle_box, 0.0, math.pi)
        _check_range("GlobalSearch", "shift_box", self.shift_box, 0.0, math.inf)
        _check_range("GlobalSearch", "restart_below", self.restart_below, 0.0, 1.0, closed_low=True)


class RotationSearch(eqx.Module):
    """The capture stage (`jaxpose._capture`): a global search over the whole rotation group
    that replaces the box search of [`GlobalSearch`][jaxpose.GlobalSearch] when set
    (`Config.so3`, see [`Config.capture`][jaxpose.Config.capture]).

    - `rotations`: size of the super-Fibonacci grid of rotations (static); the 24 alignments
      of the two clouds' principal frames are added to it.
    - `objective`: "hard" or "soft", what scores the grid on the coarse problem (static).
    - `modes`: distinct best candidates refined on the coarse problem (static).
    - `hypotheses`: distinct refined modes fitted to the surface (static); with a fit from
      rest and the three half-turn twins of the best they make the slots of
      `Estimate.hypotheses`.
    - `separation_deg`: rotations closer than this (degrees) are one mode, among the grid's
      candidates and among the refined modes that become hypotheses; fitted hypotheses closer
      than half of it are one answer (static).
    - `points`: current and previous points of the hypotheses' surface fits and of their
      consistency scores (static).
    - `wide_inlier`, `wide_rounds`: inlier gate (metres) and rounds of a hypothesis's first
      surface fit, which pulls in a translation that the grid's overlap estimate left
      centimetres off (the second fit uses `FineStage.inlier`).
    - `second_look`, `second_refined`, `second_hypotheses`: the grid's next `second_look`
      distinct modes after `modes` take the translation of the FFT correlation and are
      rescored; the best `second_refined` are refined and the best `second_hypotheses` of
      those fitted as more hypotheses (`jaxpose._capture.second_look`); `second_look` 0 turns
      this off (static).
    - `tie`: a distinct hypothesis whose consistency (`jaxpose._capture.consistency`) is
      within this of the best's makes the estimate `Status.ambiguous` (0–1). Our choice, not
      yet calibrated: the equivalent motions of an exactly symmetric target explain the
      clouds equally only up to edges, parts that hide one another and sampling, so a margin
      of a few hundredths.
    """

    rotations: int = eqx.field(static=True, default=8192)
    objective: Literal["hard", "soft"] = eqx.field(static=True, default="hard")
    modes: int = eqx.field(static=True, default=16)
    hypotheses: int = eqx.field(static=True, default=6)
    separation_deg: float = eqx.field(static=True, default=12.0)
    points: int = eqx.field(static=True, default=1024)
    wide_inlier: Scalar = 0.10
    wide_rounds: int = eqx.field(static=True, default=10)
    tie: Scalar = 0.06
    second_look: int = eqx.field(static=True, default=32)
    second_refined: int = eqx.field(static=True, default=8)
    second_hypotheses: int = eqx.field(static=True, default=2)

    def __check_init__(self):
        if self.objective not in ("hard", "soft"):
            raise ValueError(f"RotationSearch.objective must be 'hard' or 'soft', got {self.objective!r}.")
        if min(self.rotations, self.modes, self.hypotheses, self.wide_rounds) < 1 or self.points < 10:
            raise ValueError("RotationSearch needs rotations, modes, hypotheses, wide_rounds ≥ 1 and points ≥ 10.")
        if self.second_look < 0:
            raise ValueError(f"RotationSearch.second_look must be ≥ 0, got {self.second_look}.")
        if self.second_look and not 1 <= self.second_hypotheses <= self.second_refined <= self.second_look:
            raise ValueError(
                "RotationSearch needs 1 ≤ second_hypotheses ≤ second_refined ≤ second_look where second_look > 0, got "
                f"{self.second_hypotheses}, {self.second_refined}, {self.second_look}."
            )
        if self.hypotheses > self.modes:
            raise ValueError(f"RotationSearch.hypotheses ({self.hypotheses}) must not exceed modes ({self.modes}).")
        _check_range("RotationSearch", "separation_deg", self.separation_deg, 0.0, 180.0)
        _check_range("RotationSearch", "wide_inlier", self.wide_inlier, 0.0, math.inf)
        _check_range("RotationSearch", "tie", self.tie, 0.0, 1.0, closed_low=True)


REFINE_TOL = 3e-4
"""The default refine's rtol = atol, in the solver's units of 1° and 1 cm: it stops BFGS within
about 0.006° of a resting point; at 1e-5 the kinks of the neighbourhood max kept it
zig-zagging to the step limit on half the paper's pairs with the same error (docs,
Findings: the refine's tolerance)."""


class Refine(eqx.Module):
    """The local stage: an optimistix minimiser of the negated soft objective, from the
    global search's best, in coordinates of 1° and 1 cm (so `solver`'s rtol and atol are in
    those units).

    - `solver`: any `optx.AbstractMinimiser` (default BFGS with rtol = atol = `REFINE_TOL`;
      `optx.NelderMead` works too, with a larger step limit).
    - `max_steps`: its step limit (static).
    - `points`: the current points it scores, thinned evenly from the problem's (static; None:
      all of them). The refine only has to bring p into the fine stage's basin, and the soft
      objective's cost grows with the points (a close view has 20 000). With 4096 the
      realistic benchmark's pairs kept their errors (docs, Findings: cheaper stages of the
      public call).

    `Config()` has no refine: the fine stage starts from the search's best directly. On three
    draws of the realistic benchmark (448 pairs, σ 0–2 cm) the refine changed the pairs found
    by one of 406 and no false success, and its gradient of the soft objective cost about 4 s
    of the public program's compile and 10–30 ms of each call (docs, Findings: the refine in
    the default call). `Config.fast()`, `wide()`, `capture()`, `tracking()` and `thorough()`
    keep one.
    """

    solver: optx.AbstractMinimiser = optx.BFGS(rtol=REFINE_TOL, atol=REFINE_TOL)
    max_steps: int = eqx.field(static=True, default=8)
    points: int | None = eqx.field(static=True, default=4096)

    def __check_init__(self):
        if self.max_steps < 0:
            raise ValueError(f"Refine.max_steps must be ≥ 0, got {self.max_steps!r}.")
        if self.points is not None and self.points < 10:
            raise ValueError(f"Refine.points must be ≥ 10 or None, got {self.points!r}.")


COVARIANCE_SCALE = 0.119
"""Default of `FineStage.covariance_scale`: Σ = k(σ̂) σ̂² (JᵀJ)⁻¹ with k(σ̂) = scale · (1 + σ̂ /
`FineStage.covariance_noise`). The least-squares covariance σ̂² (JᵀJ)⁻¹ assumes independent
residuals; the fit's errors grow faster with the range noise than it does. Calibrated with
`COVARIANCE_NOISE` on the realistic generator's pairs (every built-in target, σ 0.5–2 cm, draws
4, 6 and 7, 378 pairs; `uv run python experiments/nees_realistic.py --calibrate` →
`results/covariance_calibration.md`): the successes' median rotation NEES is χ²(3)'s overall
and 2.28–2.38 at each noise level, against 1.81 / 2.73 / 4.00 at σ 0.5 / 1 / 2 cm with the best
constant factor (2.65)."""

COVARIANCE_NOISE = 2.5e-4
"""Default of `FineStage.covariance_noise` (metres): the residual scale σ̂ at which the
covariance's factor has doubled, k(σ̂) = `covariance_scale` · (1 + σ̂ / `covariance_noise`)
(`jaxpose._uncertainty.covariance_factor`). The calibration (`COVARIANCE_SCALE`) chose it among
0.25–8 mm and inf; at σ̂ of several millimetres the factor is nearly proportional to σ̂ (the
covariance to σ̂³). Noise-free views have σ̂ near `_fine.SIGMA_FLOOR` (0.1 mm), so a factor of
about 0.17."""

TRACKING_COVARIANCE_SCALE = 1.52
"""`FineStage.covariance_scale` of the tracker's registrations (`jp.track`,
`jp.track_against_model`): the least-squares covariance is 1.52× too small on N5 pairs with 1 cm
range noise (`experiments/nees.py`), and the tracker's filter, keyframe gates and weak-estimate
gate were tuned with this scale on the tracking benchmark. At the realistic scale the
benchmark's noise-free fragment, seen at a grazing angle, had most of its registrations
`uncertain` and lost its track (docs, Estimating)."""


class FineStage(eqx.Module):
    """The fine stage (ours, `jaxpose._fine`): point-to-plane least squares (optimistix
    Gauss–Newton, match-then-solve rounds) of the current points against planes fitted
    to the previous points, over the visible surface (the default) or near the cutting planes.

    - `prev_slab`, `curr_slab`: half-widths of the previous and current slabs around each
      cutting plane, in units of d (the previous one wider so that every current point finds
      its neighbours); inf (the default): the whole visible surface. On the realistic
      benchmark's 28 pairs of `make_cases(1)` (every target, σ 0–2 cm) the whole surface with
      4096 points a side and centroid anchors found 24 against 18 with 896 near-plane points
      (slabs of 3d / 2d, point anchors), with no false success against 2 (docs, Findings:
      the whole surface).
    - `inlier`: current points farther than this from every previous point are left out
      (metres): surface seen in only one cloud.
    - `planar_fraction`: fraction of the previous points that keep their plane, the most
      planar ones (smallest / middle scatter eigenvalue of the neighbourhood); a current
      point matched to a point without one is left out. 1 (the default): every
      neighbourhood with a defined plane, edges and corners included: there the plane of
      least scatter still holds the slides along the faces that the faces alone leave
      weak, and under range noise the planarity rank is mostly noise, so a fraction below
      1 drops points at random. `Config.paper()` and `Config.capture()` keep 0.7 (docs,
      Findings: planes at edges and corners).
    - `guard`: the fine stage's result is dropped, and the refine's kept (the search's best
      where there is no refine, then reported not converged), when its hard score is lower
      than that start's by more than this (0–1; 1 = never dropped): on random views the fit
      can slide along a face while the hard score falls from ≈ 0.9 to 0.6.
    - `from_rest`: also run from p = 0 (no motion) and keep whichever result explains more of
      the current cloud (`better_fine`): over the small motions between frames the surface
      fit's own basin often holds the truth where the pattern search settled a few degrees off
      (static).
    - `from_principal`: also run from the alignment of the two clouds' principal frames
      nearest the identity, with the translation that lines up the surface both views share
      (`jaxpose._capture.principal_start`), and keep it where it explains the current cloud
      better (the turned fits' contest, `jaxpose._estimate.contest`) (static). For views
      where neither the search's best nor rest lies in the truth's basin. Off by default: on
      two draws of the realistic benchmark (196 pairs) it found two pairs fewer, none more,
      and made the call 10–75 ms longer (docs, Findings: a start at the principal alignment).
    - `turn_deg`, `symmetry_ratio`: when two principal moments of the previous cloud are
      within `symmetry_ratio` of each other (a nearly axisymmetric view: a cylinder, a disk),
      two more runs start from the best fit turned by ±`turn_deg` degrees about the third
      axis, through the point where the previous surface's normal lines meet across it
      (`jaxpose._estimate.symmetry_centre`: a cylinder's axis) (static; 0: no such runs). A
      turn they find that explains the current cloud about as well (inlier fractions within
      0.02 under range noise, 0.01 without: `jaxpose._estimate.turn_tie`) and lies more than
      `Thresholds.ambiguous_deg` away makes the estimate `Status.ambiguous`; one that
      explains it better becomes the estimate.
      On the realistic benchmark's noisy upper stages both fits from the refine and from rest
      ended in the same wrong turn about the long axis, 14.5° off, with as many inliers as
      the truth's fit, and were reported as successes (docs, Findings: turns about a
      near-symmetry axis).
    - `points`: capacity of the current side, and of the previous side unless `prev_points`
      says otherwise (static); more points are thinned evenly.
    - `prev_points`: capacity of the previous side (static); None (the default): `points`.
      At most the problem's `Capacities.max_prev_points` slots are used, so a large value
      keeps every previous point. The previous side is the surface the current points are
      matched against; its sampling step sets the error of the matches and of the
      neighbourhood planes. Every previous point is not the default: fitted from the true
      motion on 28 pairs at σ 0.5 cm it gave median errors of 0.051° and 0.090 cm against
      0.081° and 0.082 cm, and one upper stage ended 1.07° off. On the whole realistic
      benchmark it removed the one false success and one miss at σ 0.5 cm, found one pair
      fewer at 1 cm, and each call took 24–48 % longer (docs, Findings: a dense previous side).
    - `neighbours`: neighbours of a normal fit (static).
    - `anchor`: "hybrid" (the default), "centroid" or "point" (static): each previous point's
      plane goes through its neighbourhood's centroid or through the point itself; "hybrid"
      takes the centroid for the 70 % most planar neighbourhoods (faces) and the point for
      the rest (edges, corners). With 1 cm range noise the point anchor biases registrations
      in proportion to the motion (the nearest match favours points that noise moved
      towards the current point) and the centroid removes most of it (docs, Findings: the
      fine stage's anchor). Across an edge the centroid lies inside the body, so its plane
      runs below the surface and pulls the fit towards the body: with every plane kept
      (`planar_fraction` 1) that set the centroid error's floor under noise (docs, Findings:
      the hybrid anchor). Noise-free, the plane of a neighbourhood that spans an edge misses
      the surface by micrometres to millimetres.
    - `smooth_current`: move each face-like current point (its neighbourhood among the
      70 % most planar) along its neighbourhood's normal onto the plane fitted to its
      `neighbours` nearest current points, once, when the problem is built
      (`jaxpose._fine.CurrentSide`) (static; needs `curr_slab` inf, the whole surface). It
      removes the current points' range noise along the normal, as the "hybrid" anchor does
      the previous points'. The noise-free polish, the stop's noise scale, the reported RMS
      and the covariance use the raw points. Off by default: on two draws of 56 realistic
      pairs it cut the median rotation error at σ 1 cm (0.189° → 0.094°, 0.229° → 0.210°)
      and the median centroid error at 1 and 2 cm, but found two pairs fewer at 2 cm on one
      draw, was mixed at 0.5 cm, and the neighbour search over the current cloud made the
      median call 26–100 ms longer (docs, Findings: a smoothed current side).
    - `plane_source`: which previous points each selected previous point's plane is fitted
      to (static): "selected" (the default), its `neighbours` nearest among the selected
      points; "all", its `neighbours` nearest among every previous point; "all_centroids",
      the normal among the selected points and the centroid (the "hybrid" and "centroid"
      anchors' point) among every previous point. They differ only on views of more than
      `points` previous points, which the selection thins: there the selected points'
      `neighbours` nearest span a wider patch, whose centroid lies deeper inside a curved
      surface (`_fine._planes_from_every_point`). Either costs one more neighbour search, over
      every previous point. Off by default: fitted from the true motion, "all" brought the fine
      objective's minimum nearer the truth at σ 0.5, 1 and 2 cm, but on the realistic
      benchmark's whole calls neither option kept the gain, and both found two pairs fewer at
      σ 2 cm (docs, Findings: planes among every previous point).
    - `symmetric`: two-way residuals (static): "noisy" (the default), True or False. Each
      round also matches `_fine.BACK_POINTS` previous points that have a plane (thinned
      evenly) to their nearest current points and adds their distances to those points'
      planes, fitted to the current cloud (`Problem.fine_back`, built once in
      [`jaxpose.Problem.build`][]), beside the current points' distances to the previous
      planes. Fitted from the true motion, the one-way
      fit's minimum lies several of its own standard deviations from the truth under range
      noise, farther as the noise grows (most on the faceted mesh debris); fitted both
      ways it lies nearer. True: two-way on every view (needs `prev_slab` and `curr_slab`
      inf). "noisy": two-way where both sides are the whole surface (both slabs inf) and
      the previous view shows range noise (`FineCloud.noise` ≥ `_fine.EXACT_RMS`, 1 mm),
      one-way elsewhere. Noise-free views stay one-way because there the one-way fit is
      exact and the two-way one lost a face's in-plane turn (docs, Findings: two-way
      residuals). On four draws of the realistic benchmark (672 noisy pairs) "noisy" found
      215 / 212 / 192 pairs at σ 0.5 / 1 / 2 cm against one-way's 212 / 202 / 186 and cut
      every median error; on the realistic benchmark the warm call on noisy views took
      137–169 ms against 95–108 ms one-way (docs, Findings: two-way residuals on noisy
      views; back matches by graph descent). The noise-free polish stays one-way (its
      planes through the points are exact). The tracker's registrations and
      `Config.capture()` / `Config.tracking()` stay one-way (False): the tracking and capture
      benchmarks were measured one-way, and the tracker was worse two-way. "finish": as
      "noisy", but the fits run one-way and a last pass from the best of them adds the
      two-way residuals (`jaxpose._estimate.fine_passes`), so that the two-way matching runs
      in one pass instead of in every fit. On the same four
      draws it found 215 / 205 / 194 pairs at σ 0.5 / 1 / 2 cm with 0 / 0 / 4 false
      successes, against "noisy"'s 215 / 212 / 192 and 0 / 0 / 3, in a median of 139 / 153 /
      147 ms against 148 / 166 / 184 ms in the same run (before the back matches descended
      the graph; docs, Findings: a two-way finish instead of two-way fits). Not the default:
      it follows the one-way fits' choice between minima, which two-way fits get right more
      often at σ 1 cm.
    - `residual`: "point_to_plane" (the default) or "plane_to_plane" (static; needs
      `prev_slab` and `curr_slab` inf and `prev_points` None). "plane_to_plane" is GICP's
      cost for planar neighbourhoods: each current point also gets its own plane, fitted to
      the current cloud as the previous side's are (`Problem.fine_back`), and each round
      measures its distance along the mean of the two matched normals, weighted by
      2ε / (1 − cos θ + 2ε) with θ the angle between them and ε = `_fine.PLANE_EPSILON`
      (the weight of two planes of covariance diag(ε, 1, 1) whose normals differ by θ), so
      that a match across an edge, or between noisy normals, counts less
      (`_fine.combined_planes`). The noise-free polish stays point-to-plane. Off by default:
      on four draws of the realistic benchmark (896 pairs) it was worse than point-to-plane
      at σ 0.5, 1 and 2 cm, with 28 false successes against 9 (docs, Findings: four draws
      at once).
    - `covariance_scale`, `covariance_noise` (metres): Σ = k(σ̂) σ̂² (JᵀJ)⁻¹ with
      k(σ̂) = scale · (1 + σ̂ / noise), the factor that makes the fine stage's least-squares
      covariance (`Estimate.covariance`, and with it `Status.uncertain`) consistent with its
      errors on realistic pairs at every noise level (`COVARIANCE_SCALE`, 0.119, and
      `COVARIANCE_NOISE`, 0.25 mm; σ̂ is `Estimate.residual_scale`): the residuals of
      neighbouring points are not independent (the planes fitted to noisy or curved
      neighbourhoods tilt, and neighbours share the tilt), so the plain least-squares
      covariance is too tight, the more so the noisier the views. `covariance_noise` = inf
      makes the factor constant. The tracker's registrations use the constant
      `TRACKING_COVARIANCE_SCALE` (1.52), the scale its filter was tuned with.
    - `rounds`: most match-then-solve rounds (static).
    - `steps`, `tol`: Gauss–Newton's step limit per round and its rtol = atol, in units
      of 1° and 1 cm (static). At 1e-4, on the paper's pairs × 3 keys every result is within
      0.00004° / 0.00004 cm of the truth, as at 1e-6, with a median of 14.5 steps against 35
      (docs, Findings: the fine stage's tolerance).
    """

    prev_slab: Scalar = math.inf
    curr_slab: Scalar = math.inf
    inlier: Scalar = 0.03
    planar_fraction: Scalar = 1.0
    guard: Scalar = 0.05
    from_rest: bool = eqx.field(static=True, default=True)
    from_principal: bool = eqx.field(static=True, default=False)
    turn_deg: float = eqx.field(static=True, default=15.0)
    symmetry_ratio: Scalar = 0.85
    points: int = eqx.field(static=True, default=4096)
    prev_points: int | None = eqx.field(static=True, default=None)
    neighbours: int = eqx.field(static=True, default=20)
    anchor: Literal["point", "centroid", "hybrid"] = eqx.field(static=True, default="hybrid")
    smooth_current: bool = eqx.field(static=True, default=False)
    plane_source: Literal["selected", "all", "all_centroids"] = eqx.field(static=True, default="selected")
    symmetric: bool | Literal["noisy", "finish"] = eqx.field(static=True, default="noisy")
    residual: Literal["point_to_plane", "plane_to_plane"] = eqx.field(static=True, default="point_to_plane")
    rounds: int = eqx.field(static=True, default=20)
    steps: int = eqx.field(static=True, default=20)
    tol: float = eqx.field(static=True, default=1e-4)
    covariance_scale: Scalar = COVARIANCE_SCALE
    covariance_noise: Scalar = COVARIANCE_NOISE

    @property
    def whole_surface(self) -> bool:
        """Whether both sides are the whole visible surface (`prev_slab` = `curr_slab` = inf)."""
        return not (math.isfinite(self.curr_slab) or math.isfinite(self.prev_slab))

    @property
    def two_way(self) -> bool:
        """Whether the fine stage can add two-way residuals (`symmetric` True, or "noisy" or "finish" on the
        whole surface): the problem then holds the current side's planes (`Problem.fine_back`)."""
        return self.symmetric is True or (self.symmetric in ("noisy", "finish") and self.whole_surface)

    def __check_init__(self):
        if self.anchor not in ("centroid", "point", "hybrid"):
            raise ValueError(f"FineStage.anchor must be 'hybrid', 'centroid' or 'point', got {self.anchor!r}.")
        if self.plane_source not in ("selected", "all", "all_centroids"):
            raise ValueError(
                f"FineStage.plane_source must be 'selected', 'all' or 'all_centroids', got {self.plane_source!r}."
            )
        if self.residual not in ("point_to_plane", "plane_to_plane"):
            raise ValueError(f"FineStage.residual must be 'point_to_plane' or 'plane_to_plane', got {self.residual!r}.")
        if self.residual == "plane_to_plane" and (
            math.isfinite(self.curr_slab) or math.isfinite(self.prev_slab) or self.prev_points is not None
        ):
            raise ValueError(
                "FineStage.residual='plane_to_plane' needs the whole surface on both sides (prev_slab = curr_slab = "
                "inf) and prev_points None: each current point's own plane is fitted among the same selection."
            )
        if min(self.points, self.neighbours - 2, self.steps, self.rounds) < 1 or not self.tol > 0:
            raise ValueError("FineStage needs points ≥ 1, neighbours ≥ 3, steps ≥ 1, rounds ≥ 1 and tol > 0.")
        if self.symmetric not in (True, False, "noisy", "finish"):
            raise ValueError(f"FineStage.symmetric must be True, False, 'noisy' or 'finish', got {self.symmetric!r}.")
        if self.symmetric is True and not self.whole_surface:
            raise ValueError(
                "FineStage.symmetric needs the whole surface on both sides (prev_slab = curr_slab = inf): each side's "
                "points are matched against the other side's planes."
            )
        if self.smooth_current and math.isfinite(self.curr_slab):
            raise ValueError(
                "FineStage.smooth_current needs the whole surface (curr_slab = inf): near the cutting planes the "
                "current points are chosen at each run's start."
            )
        if self.prev_points is not None and self.prev_points < 1:
            raise ValueError(f"FineStage.prev_points must be ≥ 1 or None, got {self.prev_points!r}.")
        for name in ("prev_slab", "curr_slab", "inlier"):
            _check_range("FineStage", name, getattr(self, name), 0.0, math.inf)
        _check_range("FineStage", "planar_fraction", self.planar_fraction, 0.0, 1.0)
        _check_range("FineStage", "turn_deg", self.turn_deg, 0.0, 180.0, closed_low=True)
        _check_range("FineStage", "symmetry_ratio", self.symmetry_ratio, 0.0, 1.0)
        _check_range("FineStage", "guard", self.guard, 0.0, 1.0, closed_low=True)
        _check_range("FineStage", "covariance_scale", self.covariance_scale, 0.0, math.inf)
        _check_range("FineStage", "covariance_noise", self.covariance_noise, 0.0, math.inf)


class Thresholds(eqx.Module):
    """What counts as a result and what counts as input.

    - `min_score`: a result whose hard score is below this is reported as low-score (0–1).
      On the 100-pair capture set the results ≥ 5° off that reported success had hard scores
      0.54–0.73 (8 of 11 below 0.7) and the correct ones 0.65–0.97 (2 of 74 below 0.7); with
      2 cm range noise correct results scored 0.75–0.79.
    - `max_range`: clouds with a point farther than this from the camera (metres) are refused
      at the Python boundary (wrong units or garbage, not lidar returns).
    - `ambiguous_deg`: two surface fits (from the pattern search's result, from rest with
      `FineStage.from_rest`, or turned about a near-symmetry axis, `FineStage.turn_deg`) that
      explain the current cloud equally well (inlier fractions within 0.01) but whose
      rotations differ by more than this (degrees) make the estimate `Status.ambiguous`. On
      the realistic subset (3 pairs per target and noise level) such pairs were the upper
      stage's turns about its long axis, where the two fits were 7–14° apart and one of them
      wrong.
    - `max_rotation_std_deg`: a result whose predicted rotation uncertainty (the largest
      standard deviation of `Estimate.covariance`'s rotation block, degrees) exceeds this is
      reported `Status.uncertain`. The default, 1/3°, puts three standard deviations within
      the 1° that the benchmarks count as found: the fit may be right, but the clouds do not
      show that it is. `inf` turns the check off. Needs a fine stage (the covariance is its
      least squares', scaled by `FineStage.covariance_scale` and `covariance_noise`). With
      a constant calibrated scale (3.40) six of nine false successes on four draws of the
      realistic benchmark (896 pairs, debris fits 1.06–1.62° off) were uncertain, and 21 found
      pairs 0.3–0.8° off were too (docs, Findings: a calibrated covariance in the status);
      with the factor that grows with the noise, see docs, Findings: a covariance that grows
      with the noise.
    - `min_rotation_lever`: a result whose matched faces hold some turn by less than this
      lever (metres; `Estimate.hold`, `jaxpose._fine.face_holds`) is
      reported `Status.uncertain`, and `Estimate.hold.axis` names the turn. A single flat
      face seen head-on leaves the turn about its normal to the view's outline; the fit ends
      wherever its start left it while its covariance, scaled by residuals of round-off,
      promises hundredths of a degree. On 336 realistic pairs (draws 2 and 3, every target
      and noise level; `experiments/rotation_hold.py`) four noise-free views had levers below
      0.2 cm and ended 0.4–3° off (one of them a success 2° off without the check); every
      other view's lever was 1.06 cm or more (docs, Estimating). 0 turns the check off. The
      tracker's registrations run without it (`jaxpose.tracking._track.registration_config`).
      Needs a fine stage.
    - `min_translation_grip`: a result whose matched faces hold some translation by less than
      this grip (dimensionless, 0–1; `Estimate.slide`, `jaxpose._fine.face_holds`) is
      reported `Status.uncertain`, and `Estimate.slide.direction` names the translation. Two
      flat faces leave the slide along their common edge to the view's outline; on a
      noise-free N5 view of the realistic generator the fit slid 5.5 cm that way, was
      reported a success, and its covariance promised micrometres. On 336 realistic pairs
      (draws 2 and 3; `experiments/rotation_hold.py`) 17 noise-free successes had a grip
      below 0.01 and centroid errors of 0.008–3.0 cm (median 0.36 cm); every noisy view's
      grip was 0.0215 or more, as range noise scatters the fitted normals (docs,
      Estimating). 0 turns the check off. The tracker's registrations run without it, as
      without the lever. Needs a fine stage.
    """

    min_score: Scalar = 0.7
    max_range: Scalar = 1000.0
    ambiguous_deg: Scalar = 1.0
    max_rotation_std_deg: Scalar = 1.0 / 3.0
    min_rotation_lever: Scalar = 0.005
    min_translation_grip: Scalar = 0.01

    def __check_init__(self):
        _check_range("Thresholds", "min_score", self.min_score, 0.0, 1.0, closed_low=True)
        _check_range("Thresholds", "max_range", self.max_range, 0.0, math.inf)
        _check_range("Thresholds", "ambiguous_deg", self.ambiguous_deg, 0.0, 180.0)
        _check_range("Thresholds", "max_rotation_std_deg", self.max_rotation_std_deg, 0.0, math.inf)
        _check_range("Thresholds", "min_rotation_lever", self.min_rotation_lever, 0.0, math.inf, closed_low=True)
        _check_range("Thresholds", "min_translation_grip", self.min_translation_grip, 0.0, 1.0, closed_low=True)


_LEGACY = {
    **{name: ("patterns", name) for name in ("d", "extension", "slices", "bin_width", "select_width")},
    **{name: ("capacities", name) for name in ("grid_cells", "max_points", "max_prev_points", "max_cells")},
    "global_objective": ("search", "objective"),
    "coarse": ("search", "coarse_factor"),
    **{
        name: ("search", name)
        for name in (
            "coarse_points",
            "population",
            "generations",
            "angle_box",
            "shift_box",
            "recentre",
            "restarts",
            "restart_below",
        )
    },
    **{
        f"fine_{name}": ("fine", name)
        for name in (
            "prev_slab",
            "curr_slab",
            "inlier",
            "planar_fraction",
            "guard",
            "from_rest",
            "points",
            "neighbours",
            "anchor",
            "rounds",
            "steps",
            "tol",
        )
    },
    "min_score": ("thresholds", "min_score"),
    "max_range": ("thresholds", "max_range"),
}
"""The flat keyword names of the single-object configuration, and the section field each
one now is (deprecated aliases; `local*` and a string `fine` are translated apart)."""

_DEFAULT = object()


class Config(eqx.Module):
    """Settings of the plane-pattern method: one object per stage, in the order of the data
    flow. `Config()` is the default; a stage set to None (`refine`, `fine`) does not run.

    - `patterns`: [`Patterns`][jaxpose.Patterns].
    - `capacities`: [`Capacities`][jaxpose.Capacities].
    - `search`: [`GlobalSearch`][jaxpose.GlobalSearch].
    - `refine`: [`Refine`][jaxpose.Refine] or None (the default, and the paper's method, have
      none; see `Refine` for why the default has none).
    - `fine`: [`FineStage`][jaxpose.FineStage] or None.
    - `thresholds`: [`Thresholds`][jaxpose.Thresholds].
    - `so3`: [`RotationSearch`][jaxpose.RotationSearch] or None (the default): the capture
      stage over the whole rotation group, in place of the box search (`Config.capture()`).

    Change one setting with `dataclasses.replace`, e.g.
    `dataclasses.replace(config, fine=dataclasses.replace(config.fine, points=8192))`, or
    build the section: `jp.Config(capacities=jp.Capacities(max_points=6144))`.

    The flat keywords of the single-object configuration (`max_points=…`, `fine_points=…`,
    `local="nelder_mead"`, `fine="none"`, …) and reading them as attributes are deprecated
    aliases: they still work and warn.
    """

    patterns: Patterns
    capacities: Capacities
    search: GlobalSearch
    refine: Refine | None
    fine: FineStage | None
    thresholds: Thresholds
    so3: RotationSearch | None

    def __init__(
        self,
        patterns: Patterns | None = None,
        capacities: Capacities | None = None,
        search: GlobalSearch | None = None,
        refine=_DEFAULT,
        fine=_DEFAULT,
        thresholds: Thresholds | None = None,
        so3: RotationSearch | None = None,
        **legacy,
    ):
        sections = {
            "patterns": Patterns() if patterns is None else patterns,
            "capacities": Capacities() if capacities is None else capacities,
            "search": GlobalSearch() if search is None else search,
            "refine": None if refine is _DEFAULT else refine,
            "fine": FineStage() if fine is _DEFAULT else fine,
            "thresholds": Thresholds() if thresholds is None else thresholds,
            "so3": so3,
        }
        if isinstance(sections["fine"], str):  # the flat `fine="none" | "point_to_plane"`
            legacy["fine"] = sections.pop("fine")
            sections["fine"] = FineStage()
        if refine is _DEFAULT and {"local", "local_steps", "local_tol"} & set(legacy):
            sections["refine"] = Refine()  # the flat configuration's default refine was BFGS
        if legacy:
            sections = _apply_legacy(sections, legacy)
        if sections["so3"] is not None and sections["fine"] is None:
            raise ValueError("Config.so3 (the capture stage) fits its hypotheses with the fine stage: set Config.fine.")
        for name, value in sections.items():
            setattr(self, name, value)

    def __getattr__(self, name: str):
        if name in _LEGACY or name in ("local", "local_steps", "local_tol"):
            warnings.warn(
                f"Config.{name} is deprecated: read it from the config's sections.", DeprecationWarning, stacklevel=2
            )
            return _legacy_value(self, name)
        raise AttributeError(f"'Config' object has no attribute {name!r}")

    @property
    def num_planes(self) -> int:
        return self.patterns.num_planes

    def with_capacities(self, **sizes: int) -> Config:
        """This config with each capacity left at None set from `sizes` (names of
        [`Capacities`][jaxpose.Capacities]); capacities already set are kept."""
        return dataclasses.replace(self, capacities=self.capacities.filled(**sizes))

    def with_jit_capacities(self, prev_rows: int, curr_rows: int) -> Config:
        """This config with each capacity left at None set for traced clouds of `prev_rows` and
        `curr_rows` rows: the row counts for the points, `JIT_GRID_CELLS` and `JIT_MAX_CELLS`."""
        return self.with_capacities(
            max_prev_points=prev_rows, max_points=curr_rows, grid_cells=JIT_GRID_CELLS, max_cells=JIT_MAX_CELLS
        )

    def sized_for(self, camera, extent: float, distance: float | None = None) -> Config:
        """This config with its capacities sized for a target of largest extent `extent`
        (metres) seen by `camera` at `distance` (metres; default the nearest the target fits
        in the field of view, never below `camera.range_min`): for code that calls
        `estimate` under `jax.jit`, where the clouds cannot size it.

        - points: the pixels the target's bounding sphere can cover at that distance (at most
          the camera's frame);
        - `grid_cells`: (1 + 2·extension)·extent/d + 3 cells plus the margin of `sized_config`;
        - `max_cells`: 4π·extent/d, twice the cells along the outline of a slab through a
          convex body of that size, at least `JIT_MAX_CELLS` / 4.

        Each is rounded up by `bucket`; capacities already set are kept."""
        from ._problem import GRID_MARGIN, bucket

        tan_half = min(float(camera.tan_half_x), float(camera.tan_half_y))
        fit = extent / 2 / tan_half
        distance = max(fit, float(camera.range_min)) if distance is None else distance
        radius = extent / 2
        half_angle = math.asin(min(1.0, radius / max(distance, radius)))
        share = min(
            1.0, (math.tan(half_angle) / float(camera.tan_half_x)) * (math.tan(half_angle) / float(camera.tan_half_y))
        )
        frame = camera.width * camera.height
        pixels = min(bucket(math.ceil(share * frame) + 1, 512), frame)  # never more than a frame
        cells = (1 + 2 * self.patterns.extension) * extent / self.patterns.d + 3 + GRID_MARGIN
        max_cells = bucket(max(math.ceil(4 * math.pi * extent / self.patterns.d), JIT_MAX_CELLS // 4), 64)
        return self.with_capacities(
            max_points=pixels, max_prev_points=pixels, grid_cells=bucket(math.ceil(cells), 32), max_cells=max_cells
        )

    @property
    def coarse_config(self) -> Config:
        """The settings of the coarse problem of the search (see `GlobalSearch.coarse_factor`):
        cells and selection of `coarse_factor`·d, a grid of ⌈C / coarse_factor⌉ + 2 cells,
        `coarse_points` current points, no fine stage."""
        factor = self.search.coarse_factor
        return Config(
            patterns=dataclasses.replace(self.patterns, d=self.patterns.d * factor),
            capacities=dataclasses.replace(
                self.capacities,
                grid_cells=-(-self.capacities.grid_cells // factor) + 2,
                max_points=self.search.coarse_points,
            ),
            search=dataclasses.replace(self.search, coarse_factor=1),
            refine=self.refine,
            fine=None,
            thresholds=self.thresholds,
        )

    @classmethod
    def paper(cls, **changes) -> Config:
        """The paper's setting: three planes, d = 0.026 m whatever the data, the hard objective, one CMA-ES
        search (48 × 60) in the ±20° / ±0.10 m box on the full patterns, no refine and no fine
        stage. `changes`: sections to replace."""
        search = GlobalSearch(objective="hard", coarse_factor=1, population=48, generations=60, recentre=0)
        patterns = Patterns(cell_steps=0.0)
        return cls(**{"patterns": patterns, "search": search, "refine": None, "fine": None, **changes})

    @classmethod
    def fast(cls, **changes) -> Config:
        """The default's search with the fine stage on the points near the cutting planes (896
        a side, slabs of 3d / 2d, planes through the points): several times cheaper than the
        whole surface, and exact on noise-free pairs of flat faces; less accurate under range
        noise ([`FineStage`][jaxpose.FineStage]). The tests run it on the paper's pairs."""
        fine = FineStage(prev_slab=3.0, curr_slab=2.0, points=896, anchor="point", planar_fraction=0.7)
        return cls(**{"refine": Refine(), "fine": fine, **changes})

    @classmethod
    def wide(cls, **changes) -> Config:
        """Capture, for a first estimate with no prior (`jaxpose compare --set capture`): a
        ±90° / ±0.30 m box searched on the full patterns by a larger CMA-ES (64 × 60), up to 7
        restarts while the best soft score is below 0.8, three slices per axis (9 planes), up
        to 100 BFGS steps and a fine stage near the planes (2048 points a side).

        Why 9 planes: over ±90° the three-plane objective has wrong maxima (a ≈ 90° turn that
        lines up flat faces, or a few degrees' slide along a symmetric part) that can score
        above the truth; nine planes rank some of them below it, so restarts leave them. With
        both, the capture set went from 84 to 95 found of 100. 9 planes score three times the
        patterns per evaluation."""
        search = GlobalSearch(
            coarse_factor=1,
            population=64,
            generations=60,
            angle_box=math.radians(90.0),
            shift_box=0.30,
            restarts=7,
        )
        base = {**_full_search_sections(), "patterns": Patterns(slices=3), "search": search}
        return cls(**{**base, **changes})

    @classmethod
    def capture(cls, **changes) -> Config:
        """Capture at any rotation, for a first estimate with no prior: the global stage over the
        whole rotation group ([`RotationSearch`][jaxpose.RotationSearch], 8192 super-Fibonacci
        rotations and the principal-frame alignments scored on the coarse problem, 16 modes
        refined, 6 hypotheses, 2 more from the second look at the next 32 modes and a start
        from rest fitted to the surface, and three half-turn twins), then the default
        fine stage from the best hypothesis. `Estimate.hypotheses` holds the distinct
        hypotheses, best first; `Estimate.ambiguous` says that another one explains the clouds
        as well (a symmetric target). Up to 30 BFGS steps per mode. The fine stage keeps
        `planar_fraction` 0.7 and planes through the centroids (`anchor` "centroid"), as when
        the capture benchmark was measured: with every plane, noise-free N5 lost one of its
        four equivalent motions from the hypotheses (`tests/test_capture.py`)."""
        fine = FineStage(planar_fraction=0.7, anchor="centroid", symmetric=False)
        base = {"so3": RotationSearch(), "refine": Refine(max_steps=30), "fine": fine}
        return cls(**{**base, **changes})

    @classmethod
    def tracking(cls, **changes) -> Config:
        """Frame-to-frame registration of noisy clouds (`jaxpose.track`): the search on the full
        patterns (CMA-ES 32 × 40, up to 100 BFGS steps) and the fine stage over the whole
        cloud, 6144 points a side, planes through the neighbourhood centroids on faces (the
        default "hybrid" anchor).

        Why: with 1 cm range noise the fine stage's error falls as more surface is fitted. On
        the 10 s N5 tumbles of `experiments/tumble_tracking.py` (4.5 °/s, 5.5 m) 247–250 of
        251 frames of six seeds succeeded, with registration errors of median 0.043–0.062°.
        It is slower per pair than the default (a neighbour search over 6144 points)."""
        fine = FineStage(points=6144, guard=1.0, tol=1e-6, symmetric=False)
        return cls(**{**_full_search_sections(), "fine": fine, **changes})

    @classmethod
    def accurate(cls, **changes) -> Config:
        """Deprecated: the default, `Config()`."""
        warnings.warn("Config.accurate() is the default: use Config().", DeprecationWarning, stacklevel=2)
        return cls(**changes)

    @classmethod
    def thorough(cls, **changes) -> Config:
        """Deprecated: the search on the full patterns (CMA-ES 32 × 40, up to 100 BFGS steps)
        and the fine stage near the planes with 2048 points a side, no guard; kept for the
        experiments whose committed figures were measured with it."""
        warnings.warn("Config.thorough() is deprecated; build the sections you need.", DeprecationWarning, stacklevel=2)
        return cls(**{**_full_search_sections(), **changes})


def _full_search_sections() -> dict:
    """The sections shared by `wide`, `tracking` and the deprecated `thorough`: the search on
    the full patterns (CMA-ES 32 × 40), up to 100 BFGS steps on all the current points, and a
    fine stage near the planes (2048 points a side, slabs of 3d / 2d, planes through the
    points, no guard, tolerance 1e-6)."""
    return {
        "search": GlobalSearch(coarse_factor=1, population=32, generations=40),
        "refine": Refine(max_steps=100, points=None),
        "fine": FineStage(prev_slab=3.0, curr_slab=2.0, points=2048, anchor="point", guard=1.0, tol=1e-6),
    }


def _apply_legacy(sections: dict, legacy: dict) -> dict:
    """Apply the deprecated flat keywords to the sections (see `_LEGACY`)."""
    unknown = set(legacy) - set(_LEGACY) - {"local", "local_steps", "local_tol", "fine"}
    if unknown:
        raise TypeError(f"Config got unexpected keyword arguments {sorted(unknown)}.")
    warnings.warn(
        f"flat Config keywords {sorted(legacy)} are deprecated: pass the sections "
        "(Patterns, Capacities, GlobalSearch, Refine, FineStage, Thresholds).",
        DeprecationWarning,
        stacklevel=3,
    )
    legacy = dict(legacy)
    fine_mode = legacy.pop("fine", None)
    if fine_mode not in (None, "none", "point_to_plane"):
        raise ValueError(f"fine must be 'point_to_plane' or 'none', got {fine_mode!r}.")
    grouped: dict[str, dict] = {}
    for name, value in legacy.items():
        if name in _LEGACY:
            section, field = _LEGACY[name]
            grouped.setdefault(section, {})[field] = value
    for section, changes in grouped.items():
        if section == "fine" and sections["fine"] is None:
            sections["fine"] = FineStage()
        sections[section] = dataclasses.replace(sections[section], **changes)
    if fine_mode == "none":
        sections["fine"] = None
    elif fine_mode == "point_to_plane" and sections["fine"] is None:
        sections["fine"] = FineStage()
    if {"local", "local_steps", "local_tol"} & set(legacy):
        sections["refine"] = _legacy_refine(sections["refine"], legacy)
    return sections


def _legacy_refine(refine: Refine | None, legacy: dict) -> Refine | None:
    """The refine that the deprecated `local`, `local_steps` and `local_tol` describe, on top of
    `refine`: `local` picks the solver (unchanged when absent), `local_tol` its rtol = atol."""
    kind = legacy.get("local")
    if kind == "none" or (kind is None and refine is None):
        return None
    solvers = {"bfgs": optx.BFGS, "nelder_mead": optx.NelderMead}
    if kind is not None and kind not in solvers:
        raise ValueError(f"local must be 'bfgs', 'nelder_mead' or 'none', got {kind!r}.")
    base = Refine() if refine is None else refine
    solver = base.solver
    if kind is not None or "local_tol" in legacy:
        tol = legacy.get("local_tol", base.solver.rtol)
        solver = solvers.get(kind, type(base.solver))(rtol=tol, atol=tol)
    return Refine(solver, legacy.get("local_steps", base.max_steps), base.points)


def _legacy_value(config: Config, name: str):
    """The value a deprecated flat name reads; a stage switched off reads its defaults."""
    refine = Refine() if config.refine is None else config.refine
    if name == "local":
        if config.refine is None:
            return "none"
        return "nelder_mead" if isinstance(refine.solver, optx.NelderMead) else "bfgs"
    if name == "local_steps":
        return refine.max_steps
    if name == "local_tol":
        return refine.solver.rtol
    section, field = _LEGACY[name]
    part = getattr(config, section)
    return getattr(FineStage() if part is None else part, field)


JIT_GRID_CELLS = 256
"""`grid_cells` under jit when the config leaves it at None: with the default d and
extension, patterns up to about 4.7 m across."""

JIT_MAX_CELLS = 2048
"""`max_cells` under jit when the config leaves it at None."""
