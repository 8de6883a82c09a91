"""Fuzzing the public entry points with hypothesis (issue 6): odd and bad inputs get a
documented ValueError at the Python boundary, or a result with an honest status — never a
crash, never a NaN pose reported as success. ≥ 1000 generated inputs in the default run;
shapes are fixed per entry point so each compiles once."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxpose as jp
from jaxpose._estimate import STATUS_TEXT, SUCCESS

N = 200  # points per fuzzed cloud: one shape, one compile
# Every capacity fixed, and large enough for any N-point cloud that is not refused, so that
# each entry point compiles once (sized capacities would give each fuzzed cloud its bucket).
CAPACITIES = jp.Capacities(max_points=256, max_prev_points=256, grid_cells=128, max_cells=256)
CONFIG = jp.Config.fast(
    search=jp.GlobalSearch(population=8, generations=4),
    refine=jp.Refine(max_steps=5),
    fine=dataclasses.replace(jp.Config.fast().fine, points=256),
    capacities=CAPACITIES,
)
FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)

KINDS = ("blob", "collinear", "coplanar", "duplicates", "ambiguous", "huge", "tiny", "far", "ints")


@st.composite
def clouds(draw, n=N):
    """A cloud of fixed size N with an odd geometry, mask and sprinkled non-finite values."""
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    kind = draw(st.sampled_from(KINDS))
    spreads = {
        "blob": [0.5, 0.3, 0.15],
        "collinear": [0.5, 0.0, 0.0],
        "coplanar": [0.5, 0.3, 0.0],
        "duplicates": [0.0, 0.0, 0.0],
        "ambiguous": [0.3, 0.3, 0.3],
    }.get(kind, [0.5, 0.3, 0.15])
    pts = rng.uniform(-1, 1, (n, 3)) * spreads + [0.0, 0.0, 5.0]
    if kind == "ambiguous":
        pts = rng.normal(size=(n, 3))
        pts = 0.3 * pts / np.linalg.norm(pts, axis=1, keepdims=True) + [0, 0, 5.0]
    pts = pts * {"huge": 1e6, "tiny": 1e-6}.get(kind, 1.0) + (1e7 if kind == "far" else 0.0)
    if kind == "ints":
        pts = np.round(pts).astype(np.int32)
    valid = rng.uniform(size=n) < draw(st.sampled_from([1.0, 0.9, 0.05, 0.0]))
    if draw(st.booleans()) and kind != "ints":  # sprinkle NaN/inf into valid or invalid rows
        rows = rng.integers(0, n, draw(st.integers(1, 5)))
        pts[rows, rng.integers(0, 3, rows.size)] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    return pts, valid


def _cloud(data) -> jp.Cloud:
    """A Cloud made directly (no boundary cleaning), as code under jit would make it."""
    points, valid = data
    return jp.Cloud(jnp.asarray(points), jnp.asarray(valid))


def _is_documented(err: ValueError) -> bool:
    return len(str(err)) > 10  # a message that names the problem (all ours do)


@FUZZ
@given(clouds(), st.sampled_from(["ok", "short mask", "int mask", "2d"]))
def test_from_points_raises_or_returns_finite(data, mask_kind):
    pts, valid = data
    if mask_kind == "short mask":
        valid = valid[:-1]
    elif mask_kind == "int mask":
        valid = valid.astype(np.int64)
    elif mask_kind == "2d":
        pts = pts[:, :2]
    try:
        cloud = jp.Cloud.from_points(pts, valid)
    except ValueError as err:
        assert _is_documented(err)
        return
    assert mask_kind == "ok"
    assert np.all(np.isfinite(np.asarray(cloud.points)))


def _usable_problem(prev, curr):
    """Problem.build on two fuzzed clouds: a ValueError, or a problem with status 0 and finite data."""
    try:
        problem = jp.Problem.build(_cloud(prev), _cloud(curr), CONFIG)
    except ValueError as err:
        assert _is_documented(err)
        return None
    assert int(problem.status) == 0
    for path, leaf in jax.tree_util.tree_leaves_with_path(problem):
        assert np.all(np.isfinite(np.asarray(leaf, float))), jax.tree_util.keystr(path)
    return problem


@FUZZ
@given(clouds(), clouds())
def test_problem_build_raises_or_is_usable(prev, curr):
    _usable_problem(prev, curr)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(clouds(), clouds(), st.integers(0, 2**31 - 1))
def test_estimate_never_reports_a_non_finite_success(prev, curr, seed):
    try:
        est = jp.estimate(_cloud(prev), _cloud(curr), CONFIG, key=jax.random.key(seed))
    except ValueError as err:
        assert _is_documented(err)
        return
    assert int(est.status) in STATUS_TEXT
    finite = np.all(np.isfinite(np.asarray(est.params))) and np.all(np.isfinite(np.asarray(est.rotation)))
    assert finite or int(est.status) != SUCCESS
    if int(est.status) == SUCCESS:
        assert float(est.hard) >= CONFIG.thresholds.min_score


@FUZZ
@given(
    st.lists(st.floats(-10, 10) | st.sampled_from([np.nan, np.inf]), min_size=3, max_size=3),
    st.lists(st.floats(-1e3, 1e3) | st.sampled_from([np.nan, -np.inf, 1e30]), min_size=3, max_size=3),
    st.booleans(),
)
def test_simulate_raises_or_returns_finite(angles, t, skew):
    R = np.asarray(jp.rotation(*angles)) if np.all(np.isfinite(angles)) else np.full((3, 3), np.nan)
    if skew:
        R = R * 1.01
    try:
        cloud = jp.simulate(jp.Camera.from_fov(16, 16, 0.5), jp.targets.n5(), R, np.asarray(t))
    except ValueError as err:
        assert _is_documented(err)
        return
    assert np.all(np.isfinite(cloud.compact()))
    assert not skew and np.all(np.isfinite(t))


@pytest.mark.parametrize(
    "scale, offset, dtype, match",
    [(1.0, 1e7, jnp.float64, "max_range"), (1e6, 0.0, jnp.float64, "max_range"), (1.0, 3e4, jnp.float32, "resolution")],
)
def test_far_or_huge_clouds_name_the_problem(scale, offset, dtype, match):
    """Beyond max_range, or beyond what the float type resolves at d/10 (float32 at 30 km)."""
    pts = np.random.default_rng(0).uniform(-1, 1, (N, 3)) * [0.5, 0.3, 0.15] * scale + offset
    cloud = jp.Cloud(jnp.asarray(pts, dtype), jnp.ones(N, bool))
    with pytest.raises(ValueError, match=match):
        jp.Problem.build(
            cloud,
            cloud,
            jp.Config.fast(
                capacities=jp.Capacities(max_points=256),
                thresholds=jp.Thresholds(max_range=1e5 if match == "resolution" else 1e3),
            ),
        )


@pytest.mark.parametrize(
    "section, field, value",
    [
        (jp.Patterns, "d", 0.0),
        (jp.Patterns, "d", float("nan")),
        (jp.Patterns, "bin_width", 1.5),
        (jp.Patterns, "select_width", -0.1),
        (jp.Patterns, "extension", -1.0),
        (jp.Patterns, "slices", 0),
        (jp.GlobalSearch, "angle_box", 4.0),  # radians, not degrees
        (jp.GlobalSearch, "shift_box", 0.0),
        (jp.GlobalSearch, "population", 1),
        (jp.GlobalSearch, "objective", "median"),
        (jp.GlobalSearch, "restart_below", 1.5),
        (jp.Refine, "max_steps", -1),
        (jp.FineStage, "anchor", "edge"),
        (jp.FineStage, "planar_fraction", 0.0),
        (jp.FineStage, "inlier", -0.01),
        (jp.FineStage, "prev_points", 0),
        (jp.Capacities, "max_points", 2),
        (jp.Thresholds, "min_score", 1.2),
        (jp.Thresholds, "max_range", -1.0),
    ],
)
def test_config_sections_reject_out_of_range_settings(section, field, value):
    # A value outside a Literal field's choices is a TypeError when the annotations are
    # checked (as in this test suite), the section's own ValueError otherwise; both name it.
    with pytest.raises((ValueError, TypeError), match=f"{section.__name__}.{field}|{section.__name__} needs|{field}"):
        section(**{field: value})


def test_flat_config_keywords_are_deprecated_aliases_of_the_sections():
    with pytest.warns(DeprecationWarning, match="flat Config keywords"):
        config = jp.Config.fast(max_points=512, fine_points=256, coarse=1, local="nelder_mead", local_steps=30)
    assert config.capacities.max_points == 512 and config.fine.points == 256 and config.fine.anchor == "point"
    assert config.search.coarse_factor == 1 and config.refine.max_steps == 30
    assert isinstance(config.refine.solver, optx.NelderMead)
    with pytest.warns(DeprecationWarning):
        assert config.fine_points == 256 and config.local == "nelder_mead"
    with pytest.warns(DeprecationWarning):
        assert jp.Config(fine="none", local="none").fine is None
    # The flat configuration's default had BFGS: a step limit alone still means that refine,
    # although `Config()` itself has none.
    assert jp.Config().refine is None
    with pytest.warns(DeprecationWarning):
        legacy = jp.Config(local_steps=30)
    assert legacy.refine.max_steps == 30 and isinstance(legacy.refine.solver, optx.BFGS)
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="local must"):
        jp.Config(local="newton")
    with pytest.raises(TypeError, match="unexpected"):
        jp.Config(fine_point=3)
