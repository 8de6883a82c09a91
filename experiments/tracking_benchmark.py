"""Tracking on independent random tumbles through the public call (issue 25).

Each tumble (`Tumble.random`): one target family, a random attitude, axis, rate (0.5–10 °/s)
and inertia ratios, torque-free with an inertial camera or under gravity gradient with the
camera fixed in the orbital frame, range noise σ ∈ {0, 0.5, 1, 2} cm (ToF, growing with
range), `duration` seconds at `rate_hz`. The sequence goes to `jp.track(clouds, dt,
key=...)` with the default config: capacities sized from the sequence, one compiled program.

Per tumble: the rate error at the end (°/s, the filter's ω against the true apparent rate),
its maximum over the last second, the attitude error of the filtered A = R_0k at the end (°),
registered frames (a success, or an ambiguous estimate resolved by motion continuity) and
fused frames, non-finite outputs, and the time per frame (compile excluded, measured
separately). Per family and overall: median, p90 and max.

    uv run python experiments/tracking_benchmark.py [tumbles] [duration_s] [rate_hz] [mode] [first]
        → results/tracking_benchmark[_<mode>][_from<first>].{json,md}; mode "guided":
          `guided=True`; "every25": keyframes every 25 frames, not by motion
          (`keyframe_every=25, keyframe_reach=None`); "two_way": `config=jp.Config()`, whose
          fine stage is two-way on noisy views; "unguided": `guided=False` (jp.track's
          default is guided, so "guided" runs the default); `first`: the index of the first tumble
          (20 gives a second draw of the same kinds of tumble). Every mode saves its
          registrations (`..._chains.npz`).
    uv run python experiments/tracking_benchmark.py summarise   (the table again from the JSON's rows)
    uv run python experiments/tracking_benchmark.py issue [runs]
        → results/tracking_issue_case.{json,md}: issue 25's own N5 case (`issue_tumble`),
          results/tracking_issue_case_model.{json,md}: each run against the model, and
          results/tracking_issue_case_identified.{json,md}: each run's registrations through
          `identify` (as `identified` below)
    uv run python experiments/tracking_benchmark.py registrations [name]
        → results/tracking_registrations.{json,md} (or <name>_registrations.*, e.g. for
          tracking_issue_case): the saved registrations' rotation errors
          (keyframe → k against the truth), successes apart from those motion continuity
          accepted (weak or ambiguous estimates), per family and noise level
    uv run python experiments/tracking_benchmark.py refilter '{"accel_noise": 1e-3}' [name]
        → results/tracking_refilter_<name>.{json,md}: the saved registrations of the last
          default run (`results/tracking_benchmark_chains.npz`) through `filter_keyframes`
          with other options; the registrations, so their statuses, counts and times, are
          those of the saved run.
    uv run python experiments/tracking_benchmark.py sweep [name [name ...]]
        → results/tracking_refilter_sweep.{json,md} (or <name>_refilter_sweep.*, e.g. for
          tracking_issue_case): the saved registrations of the last
          default run (or of the named runs, pooled) through `filter_keyframes` with each of
          `SWEEP`'s settings (one option moved from the default at a time, a factor on every
          measurement's covariance, and a floor added to it), rate and attitude errors at
          the end: how much the filter's tuning moves the rate goal with the registrations held fixed
    uv run python experiments/tracking_benchmark.py identified [name]
        → results/<name>_identified.{json,md} (name: tracking_benchmark, or
          tracking_benchmark_from20 for the second draw): the saved registrations of that run
          through `identify` (Euler's equations fitted over the whole window), the rate and
          attitude errors at the end of the fitted motion beside the filter's: how much a
          dynamical model moves the rate goal with the registrations held fixed
    uv run python experiments/tracking_benchmark.py model [name]
        → results/<name>_model.{json,md} (name: tracking_benchmark by default): the saved
          registrations of that run and the same clouds (simulated again with the run's keys)
          through `jp.track_against_model`: every frame registered against the body-frame
          model of the keyframes so far, filtered; the rate and attitude errors at the end
          beside the chain's, the frames fused against the model and the seconds it took
          (compile included in the first tumble's)
    uv run --extra peers python experiments/tracking_benchmark.py gicp [name]
        → results/<name>_gicp.{json,md}: a peer tracker on the same clouds (simulated again
          with the run's keys): small_gicp GICP registers each frame against the keyframe the
          saved jaxpose run used, and `filter_keyframes` filters them with jaxpose's
          covariances, so that only the registrations differ; rate and attitude errors at the
          end, registration errors keyframe → k and times beside jaxpose's
    uv run python experiments/tracking_benchmark.py gicp_table [base]
        → results/tracking_gicp[_guided].{json,md}: jaxpose's chain against the peer tracker
          on the two draws' 40 tumbles of the run `base` (tracking_benchmark, the unguided
          runs, by default; tracking_benchmark_guided), per noise level
    uv run python experiments/tracking_benchmark.py reach [tumbles] [duration_s] [rate_hz]
        → results/tracking_reach.{json,md}: how far one keyframe reaches: every frame of
          `tumbles` other random tumbles (seeds 3000 + i, not the benchmark's) registered
          against frame 0, success rate and rotation error per bin of the true rotation from
          frame 0
"""

from __future__ import annotations

import functools
import json
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose._estimate import NOT_CONVERGED, SUCCESS
from jaxpose._problem import sized_sequence_config
from jaxpose.sim import Tumble, simulate_sequence
from jaxpose.sim._sequence import C_FROM_O
from jaxpose.tracking._identify import identify_tracked
from jaxpose.tracking._track import (
    FILTER_UPDATED,
    Chain,
    _track_program,
    chain_estimates,
    chained_motions,
    filter_keyframes,
    is_registered,
)

FAMILIES = ("n5", "chibis_m", "satellite", "upper_stage", "fragment")
NOISE_CM = (0.0, 0.5, 1.0, 2.0)
FILTERED = ("attitude", "rate", "spin_accel", "position", "velocity", "rate_std")


def true_rates(R: np.ndarray, rate_hz: float) -> np.ndarray:
    """Apparent angular velocity (rad/s, frame c) at each frame from consecutive true poses."""
    rate = np.stack([np.asarray(jaxlie.SO3.from_matrix(R[k + 1] @ R[k].T).log()) * rate_hz for k in range(len(R) - 1)])
    return np.concatenate([rate[:1], rate])


BENCHMARK_SEEDS = 1000
"""Seed base of the benchmark's tumbles (`draw_tumble`); `reach` draws others (`REACH_SEEDS`)."""

REACH_SEEDS = 3000

MODES = {
    "default": {},
    "guided": {"guided": True},
    "unguided": {"guided": False},
    "every25": {"keyframe_every": 25, "keyframe_reach": None},
    "two_way": {"config": jp.Config()},
}
"""`jp.track` options of each benchmark mode; "guided" is the default's (`jp.track`'s
registrations are guided by the predicted motion), "unguided" `guided=False`;
"two_way": the registrations with `Config()`'s fine stage, two-way on noisy views (the
tracker's default is one-way)."""


def draw_tumble(index: int, seed_base: int) -> tuple[str, float, Tumble, jax.Array]:
    """Tumble `index` of a draw: its family and noise level (cm) in turn, the camera inertial
    for even indices and orbital for odd ones, `Tumble.random` from the key `seed_base` +
    `index` (folded with 0; 1 and 2 give the simulation's and the tracker's keys)."""
    family = FAMILIES[index % len(FAMILIES)]
    sigma = NOISE_CM[(index // len(FAMILIES)) % len(NOISE_CM)]
    key = jax.random.key(seed_base + index)
    tumble = Tumble.random(jax.random.fold_in(key, 0), distance=6.0, orbital_camera=bool(index % 2))
    return family, sigma, tumble, key


def simulate_tumble(family: str, sigma: float, tumble: Tumble, key, duration: float, rate_hz: float):
    """The tumble's clouds (`simulate_sequence`) seen by the CamCube with range noise `sigma`
    cm at 5 m, growing with range."""
    camera = jp.Camera.camcube2(noise_sigma=sigma / 100, noise_range_ref=5.0)
    target = getattr(jp.targets, family)()
    return simulate_sequence(camera, target, tumble, duration, rate_hz, key=jax.random.fold_in(key, 1))


def one_tumble(index: int, duration: float, rate_hz: float, options: dict | None = None) -> dict:
    family, sigma, tumble, key = draw_tumble(index, BENCHMARK_SEEDS)
    return run_tumble(index, family, sigma, tumble, key, duration, rate_hz, options)


ISSUE_MOMENTS = (1.0, 1.4, 1.9)
"""Principal moments of the issue's own case (N5, torque-free, issue 25), relative."""


def issue_tumble() -> Tumble:
    """Issue 25's case: N5 5.5 m from a camera holding an inertial attitude, torque-free with
    principal moments 1 : 1.4 : 1.9, turning at 4.5 °/s about the non-principal body axis
    (1, 2, 3)/√14 (`Tumble.n5`'s), in the paper's previous attitude."""
    base = Tumble.n5(rate_deg_s=4.5, distance=5.5)
    inertia = jnp.diag(jnp.asarray(ISSUE_MOMENTS)) * 100.0
    return eqx.tree_at(lambda t: (t.inertia, t.orbit_rate), base, (inertia, 0.0))


def run_tumble(index, family, sigma, tumble, key, duration, rate_hz, options=None) -> dict:
    """Simulate one tumble (range noise `sigma` cm at 5 m, growing with range), track it with
    the default config and measure it (see the module docstring)."""
    orbital = bool(tumble.orbit_rate)
    seq = simulate_tumble(family, sigma, tumble, key, duration, rate_hz)
    clouds = jax.block_until_ready(seq.clouds)
    _track_program.last_compile_s = 0.0
    t0 = time.perf_counter()
    track_key = jax.random.fold_in(key, 2)
    result = jax.block_until_ready(jp.track(clouds, 1 / rate_hz, key=track_key, **(options or {})))
    seconds = time.perf_counter() - t0
    compile_s = _track_program.last_compile_s
    R = np.asarray(seq.rotations)
    row = {
        "tumble": index,
        "family": family,
        "sigma_cm": sigma,
        "camera": "orbital" if orbital else "inertial",
        "rate_deg_s": float(np.degrees(np.linalg.norm(np.asarray(tumble.rate)))),
        **filter_errors(result, R, rate_hz),
        "compile_s": compile_s,
        "ms_per_frame": 1000 * (seconds - compile_s) / (len(R) - 1),
    }
    SAVED.append({"truth": R, **{name: np.asarray(getattr(result, name)) for name in REGISTRATIONS}})
    return row


REGISTRATIONS = ("rotations", "points", "status", "keyframes", "measurement_cov", "continuity")
"""The fields of a `Track` that hold its registrations (what `chain_of_track` needs)."""

SAVED: list[dict] = []
"""Each tumble's registrations and true rotations, in the order run (written as an npz)."""


def filter_errors(result, R: np.ndarray, rate_hz: float) -> dict:
    """Counts and errors of a `Track` against the true rotations R (T, 3, 3) of frame 0 → k:
    registered and fused frames, non-finite outputs, the rate error at the end and its maximum
    over the last second (°/s), and the attitude error at the end (°)."""
    truth_rate = true_rates(R, rate_hz)
    rate_err = np.degrees(np.linalg.norm(np.asarray(result.rate) - truth_rate, axis=1))
    truth_A = np.einsum("kij,lj->kil", R, R[0])
    every = int(rate_hz)
    return {
        "frames": len(R),
        # Both count frame 0 (a success and the filter's start); the summary leaves it out.
        "registered": int(np.sum(np.asarray(result.registered()))),
        "by_continuity": int(np.sum(np.asarray(result.continuity))),
        "fused": int(np.sum(np.asarray(result.filter_status) == FILTER_UPDATED)),
        "non_finite": sum(int(np.sum(~np.isfinite(np.asarray(getattr(result, f))))) for f in FILTERED),
        "rate_error_deg_s": float(rate_err[-1]),
        "rate_error_last_second_max_deg_s": float(rate_err[-every:].max()),
        "attitude_error_deg": np.degrees(float(jp.rotation_angle(result.attitude[-1], truth_A[-1]))),
    }


def switched_at(keyframes: np.ndarray) -> np.ndarray:
    """`Chain.switched` of a run whose frame k was registered against frame `keyframes[k]`:
    frame 0 and every frame some later frame was registered against became keyframes."""
    switched = np.zeros(len(keyframes), bool)
    switched[np.unique(keyframes)] = True
    switched[0] = True
    return switched


def chain_of_track(saved: dict) -> Chain:
    """The `Chain` of registrations a `Track` was filtered from (its `REGISTRATIONS` fields):
    the measurement keyframe j → k of a registered frame is R_0k R_0jᵀ and t_0k − R_rel t_0j,
    with t_0k = points_k − R_0k O_n; other frames' measurements are unused by the filter."""
    R, points, keyframes = saved["rotations"], saved["points"], saved["keyframes"]
    origin = points[0]
    t = np.asarray(chained_motions(R, points)[0])
    R_rel = np.einsum("kij,klj->kil", R, R[keyframes])
    t_rel = t - np.einsum("kij,kj->ki", R_rel, t[keyframes])
    arrays = (R, t, points, saved["status"], origin, R_rel, t_rel, saved["measurement_cov"], switched_at(keyframes))
    return Chain(*(jnp.asarray(a) for a in arrays), jnp.asarray(saved["continuity"]))


def saved_tumbles(name: str = "tracking_benchmark") -> tuple[dict, list[dict]]:
    """The last default run: its JSON (`<name>.json`) and, per tumble in its rows' order, the
    saved registrations and true rotations (`<name>_chains.npz`)."""
    saved = np.load(RESULTS / f"{name}_chains.npz")
    benchmark = json.loads((RESULTS / f"{name}.json").read_text())
    fields = ("truth", *REGISTRATIONS)
    return benchmark, [{field: saved[field][i] for field in fields} for i in range(len(benchmark["rows"]))]


def derived_name(source: str, kind: str) -> str:
    """The results name of a study (`kind`) of a saved run `source`: `tracking_<kind>` for the
    last default run (`tracking_benchmark`), `<source>_<kind>` for another."""
    return f"tracking_{kind}" if source == "tracking_benchmark" else f"{source}_{kind}"


def registration_errors(name: str = "tracking_benchmark") -> None:
    """Rotation errors (°) of a run's saved registrations keyframe → k against the truth (`name`:
    the last default run, or e.g. `tracking_issue_case`), the successes apart from the frames
    motion continuity accepted → `tracking_registrations.*` (`<name>_registrations.*` for
    another run)."""
    benchmark, tumbles = saved_tumbles(name)
    out = []
    for row, tumble in zip(benchmark["rows"], tumbles, strict=True):
        chain, R = chain_of_track(tumble), tumble["truth"]
        true_rel = np.einsum("kij,klj->kil", R, R[tumble["keyframes"]])
        error = np.degrees(np.asarray(jp.rotation_angle(chain.relative_rotations, jnp.asarray(true_rel))))
        success = np.asarray(chain.status) == 0
        success[0] = False
        continuity = np.asarray(chain.continuity)
        out.append(
            {
                **{key: row[key] for key in ("tumble", "family", "sigma_cm")},
                **{
                    f"{kind}_frames": int(mask.sum())
                    for kind, mask in (("success", success), ("continuity", continuity))
                },
                **{
                    f"{kind}_error_median_deg": float(np.median(error[mask])) if mask.any() else None
                    for kind, mask in (("success", success), ("continuity", continuity))
                },
                **{
                    f"{kind}_error_max_deg": float(error[mask].max()) if mask.any() else None
                    for kind, mask in (("success", success), ("continuity", continuity))
                },
            }
        )
    head = (
        "| tumble | family | σ, cm | successes | median / max error, ° | accepted by continuity "
        "| median / max error, ° |\n|---|---|---|---|---|---|---|\n"
    )
    fmt = lambda v: "–" if v is None else f"{v:.3f}"  # noqa: E731
    table = head + "\n".join(
        f"| {r['tumble']} | {r['family']} | {r['sigma_cm']:g} | {r['success_frames']} | "
        f"{fmt(r['success_error_median_deg'])} / {fmt(r['success_error_max_deg'])} | {r['continuity_frames']} | "
        f"{fmt(r['continuity_error_median_deg'])} / {fmt(r['continuity_error_max_deg'])} |"
        for r in out
    )
    print(table)
    out_name = derived_name(name, "registrations")
    write_json(f"{out_name}.json", {"source": name, "rows": out})
    (RESULTS / f"{out_name}.md").write_text(table + "\n")


def refiltered(
    tumbles: list[dict], rate_hz: float, options: dict, floor_deg: float = 0.0, cov_scale: float = 1.0
) -> list[dict]:
    """`filter_errors` of each saved tumble's registrations (`chain_of_track`) filtered again
    by `filter_keyframes(**options)`, with every measurement's covariance times `cov_scale` and
    `floor_deg` added to its rotation uncertainty (`with_covariance`)."""
    run = jax.jit(lambda chain: filter_keyframes(chain, 1 / rate_hz, **options))
    return [
        filter_errors(run(with_covariance(chain_of_track(t), cov_scale, floor_deg)), t["truth"], rate_hz)
        for t in tumbles
    ]


def refilter(options: dict, name: str) -> None:
    """The saved registrations of the last default run through `filter_keyframes(**options)`
    → `tracking_refilter_<name>.{json,md}`."""
    benchmark, tumbles = saved_tumbles()
    duration, rate_hz = benchmark["duration_s"], benchmark["rate_hz"]
    errors = refiltered(tumbles, rate_hz, options)
    rows = [{**old, **e, "filter_options": options} for old, e in zip(benchmark["rows"], errors, strict=True)]
    write(rows, len(rows), duration, rate_hz, f"tracking_refilter_{name}")


SWEEP = (
    {},
    {"rate_noise": 1e-5},
    {"rate_noise": 1e-3},
    {"spin_accel_noise": 1e-5},
    {"spin_accel_noise": 1e-3},
    {"accel_noise": 1e-3},
    {"accel_noise": 1e-1},
    {"shared_fraction": 0.3},
    {"shared_fraction": 0.7},
    {"spin_accel_sigma": 0.003},
    {"spin_accel_sigma": 0.03},
    {"floor_deg": 0.02},
    {"floor_deg": 0.05},
    {"floor_deg": 0.1},
    {"cov_scale": 0.5},
    {"cov_scale": 2.0},
)
"""`sweep`'s settings: `filter_keyframes` options, one moved from its default at a time, and
`cov_scale`, a factor on every measurement's covariance, and `floor_deg`, a standard
deviation (°) added in quadrature to every measurement's rotation
block (the registrations' covariance is overconfident on some views: a floor tells the filter
to trust no registration beyond it)."""


QUANTILES = {"median": 0.5, "p90": 0.9, "max": 1.0}


def quantiles(rows: list[dict], column: str) -> dict[str, float]:
    """The `QUANTILES` of one column over rows."""
    values = np.array([r[column] for r in rows])
    return {name: float(np.quantile(values, q)) for name, q in QUANTILES.items()}


def cell(values: dict[str, float], names=tuple(QUANTILES)) -> str:
    """A table cell of `quantiles`' values, e.g. "0.031 / 0.262 / 0.353"."""
    return " / ".join(f"{values[name]:.3f}" for name in names)


def identified_errors(saved: dict, tumble: Tumble, rate_hz: float) -> dict:
    """The rate (°/s) and attitude (°) errors at the last frame of the motion that `identify`
    fits to one saved tumble's registrations (`identify_tracked`: Euler's equations over the
    whole window, every registration keyframe → k weighted by its covariance; an `Orbit` for
    an orbital camera), measured as `filter_errors` measures the filter's: the rate from the
    model's last two frames against `true_rates`, the attitude R_0k against the truth."""
    R = saved["truth"]
    orbit = jp.Orbit(tumble.orbit_rate, C_FROM_O) if tumble.orbit_rate else None
    registered = is_registered(jnp.asarray(saved["status"]), jnp.asarray(saved["continuity"]))
    t0 = time.perf_counter()
    dynamics = identify_tracked(
        saved["rotations"],
        saved["points"],
        registered,
        saved["keyframes"],
        saved["measurement_cov"],
        1 / rate_hz,
        orbit=orbit,
    )
    model, _ = dynamics.predict(jnp.arange(len(R)) / rate_hz)
    model = np.asarray(jax.block_until_ready(model))
    seconds = time.perf_counter() - t0
    rate = np.asarray(jaxlie.SO3.from_matrix(model[-1] @ model[-2].T).log()) * rate_hz
    truth_A = R[-1] @ R[0].T
    return {
        "identified_rate_error_deg_s": float(np.degrees(np.linalg.norm(rate - true_rates(R, rate_hz)[-1]))),
        "identified_attitude_error_deg": np.degrees(float(jp.rotation_angle(jnp.asarray(model[-1]), truth_A))),
        "observable": bool(dynamics.observable),
        "identify_s": seconds,
    }


def identified(name: str = "tracking_benchmark") -> None:
    """The saved registrations of a default run (`<name>_chains.npz`) through `identify`
    (`identified_errors`), beside the filter's errors of that run → `<name>_identified.{json,md}`.
    The first tumble compiles the fit; its time is not comparable with the others'."""
    benchmark, tumbles = saved_tumbles(name)
    rows = []
    for old, saved in zip(benchmark["rows"], tumbles, strict=True):
        _, _, tumble, _ = draw_tumble(old["tumble"], BENCHMARK_SEEDS)
        rows.append(identified_row(old, saved, tumble, benchmark["rate_hz"]))
    write_identified(rows, benchmark["duration_s"], name)


def identified_row(old: dict, saved: dict, tumble: Tumble, rate_hz: float) -> dict:
    """One tracked tumble's filter errors (its row `old`) beside `identified_errors` of its
    saved registrations `saved`."""
    row = {key: old[key] for key in ("tumble", "family", "sigma_cm", "camera", "rate_deg_s")}
    row |= {
        "filter_rate_error_deg_s": old["rate_error_deg_s"],
        "filter_attitude_error_deg": old["attitude_error_deg"],
    }
    row |= identified_errors(saved, tumble, rate_hz)
    print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    return row


def write_identified(rows: list[dict], duration: float, name: str) -> None:
    """The filter's and the identified motion's errors per family → `<name>_identified.{json,md}`."""
    columns = ("filter_rate_error_deg_s", "identified_rate_error_deg_s")
    columns += ("filter_attitude_error_deg", "identified_attitude_error_deg")
    summary = [
        {"family": family, "tumbles": len(group)} | {c: quantiles(group, c) for c in columns}
        for family, group in by_family(rows).items()
    ]
    head = (
        f"| family | tumbles | rate error at {duration:g} s, °/s, filter: median / p90 / max "
        "| identified: median / p90 / max | attitude error, °, filter: median / max | identified: median / max |\n"
        "|---|---|---|---|---|---|\n"
    )
    ends = ("median", "max")
    lines = [
        f"| {s['family']} | {s['tumbles']} | {cell(s[columns[0]])} | {cell(s[columns[1]])} "
        f"| {cell(s[columns[2]], ends)} | {cell(s[columns[3]], ends)} |"
        for s in summary
    ]
    table = head + "\n".join(lines) + "\n"
    print(table)
    write_json(f"{name}_identified.json", {"source": name, "summary": summary, "rows": rows})
    (RESULTS / f"{name}_identified.md").write_text(table)


def saved_track(saved: dict) -> jp.Track:
    """A saved run's registrations (`REGISTRATIONS`) as the `Track` that
    `jp.track_against_model` reads: its measurements, keyframes and which frames registered
    (a success or accepted by continuity: both count as success here)."""
    registered = is_registered(np.asarray(saved["status"]), np.asarray(saved["continuity"], bool))
    return jp.Track.of_measurements(
        jnp.asarray(saved["rotations"]),
        jnp.asarray(saved["points"]),
        jnp.asarray(saved["keyframes"]),
        jnp.asarray(saved["measurement_cov"]),
        status=jnp.where(jnp.asarray(registered), SUCCESS, NOT_CONVERGED),
    )


def against_model(name: str = "tracking_benchmark") -> None:
    """The saved run `name`'s tumbles tracked against the body-frame model (see the module
    docstring) → `<name>_model.{json,md}`."""
    benchmark, saved = saved_tumbles(name)
    duration, rate_hz = benchmark["duration_s"], benchmark["rate_hz"]
    rows = []
    for row, chain in zip(benchmark["rows"], saved, strict=True):
        _, _, tumble, key = draw_tumble(row["tumble"], BENCHMARK_SEEDS)
        rows.append(model_row(row, chain, tumble, key, duration, rate_hz))
    write(rows, len(rows), duration, rate_hz, f"{name}_model")


def model_row(row: dict, chain: dict, tumble: Tumble, key, duration: float, rate_hz: float) -> dict:
    """One tracked tumble (its benchmark `row` and saved registrations `chain`) again against
    the body-frame model: the clouds simulated again with the tumble's `key`, then
    `jp.track_against_model`; the errors beside the chain's and the seconds it took."""
    seq = simulate_tumble(row["family"], row["sigma_cm"], tumble, key, duration, rate_hz)
    clouds = jax.block_until_ready(seq.clouds)
    t0 = time.perf_counter()
    model = jax.block_until_ready(jp.track_against_model(clouds, saved_track(chain), 1 / rate_hz))
    seconds = time.perf_counter() - t0
    out = {
        **{k: row[k] for k in ("tumble", "family", "sigma_cm", "camera", "rate_deg_s")},
        **filter_errors(model, np.asarray(seq.rotations), rate_hz),
        "chain_rate_error_deg_s": row["rate_error_deg_s"],
        "chain_attitude_error_deg": row["attitude_error_deg"],
        "seconds": seconds,
        "ms_per_frame": 1000 * seconds / (len(seq.rotations) - 1),
    }
    print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()}, flush=True)
    return out


GICP_SETTINGS = {
    "registration_type": "GICP",
    "downsampling_resolution": 0.01,
    "max_correspondence_distance": 0.3,
    "max_iterations": 100,
    "num_threads": 2,
}
"""small_gicp's settings in the peer tracker (`gicp_chain`): the realistic benchmark's 1 cm
downsampling and 100 iterations (`jaxpose.evaluation.peers`), issue 21's 0.3 m correspondence
distance, small_gicp's own stop (a step below 0.1° and 1 mm). A stop at 0.01° or 0.001° gave
the same registration errors on two noisy tumbles (N5 at 1 cm, the satellite at 0.5 cm:
medians 0.161–0.171° and 0.106–0.109° keyframe → frame) at two to three times the time, as
under range noise the steps seldom fall that low (a scratch check, not committed)."""


def gicp_align(prev: np.ndarray, curr: np.ndarray, init: np.ndarray):
    """small_gicp GICP (`GICP_SETTINGS`) of the previous points onto the current ones ((N, 3),
    frame c, m) from the motion `init` (4 × 4): the motion x ↦ R x + t (4 × 4), whether it
    converged within `GICP_SETTINGS`' stop, and whether it is finite."""
    import small_gicp

    result = small_gicp.align(
        np.asarray(curr, np.float64), np.asarray(prev, np.float64), init_T_target_source=init, **GICP_SETTINGS
    )
    T = np.asarray(result.T_target_source)
    return T, bool(result.converged), bool(np.all(np.isfinite(T)))


def jaxpose_covariances(saved: dict) -> np.ndarray:
    """A saved run's measurement covariance (T, 6, 6) of each frame it registered with a finite
    one, and elsewhere the mean of those (frame 0, registered against itself, left out of the
    mean)."""
    cov = np.array(saved["measurement_cov"])
    registered = np.asarray(is_registered(np.asarray(saved["status"]), np.asarray(saved["continuity"], bool)))
    own = registered & np.all(np.isfinite(cov), axis=(1, 2))
    averaged = own.copy()
    averaged[0] = False
    cov[~own] = cov[averaged].mean(axis=0)
    return cov


def gicp_chain(clouds: jp.Cloud, saved: dict) -> tuple[Chain, float, int]:
    """The peer's chain on one tumble's clouds: frame k registered by GICP (`gicp_align`)
    against the keyframe the saved jaxpose run registered it against (`saved["keyframes"]`),
    from the previous frame's motion when that used the same keyframe, else from the
    identity. Each measurement takes jaxpose's covariance of that frame where jaxpose
    registered it, else the mean of its registered ones (`jaxpose_covariances`), so that the
    filter weighs both chains alike and only the motions differ. Every finite GICP result is
    registered, as a user would take it; the frames on which it met its stop are counted
    (returned). Chained as `Chain` does (R_0k = R_rel R_0j, t_0k = R_rel t_0j +
    t_rel; a failed frame keeps the last chained motion), tracked point from frame 0's plane
    origin (`saved["points"][0]`). Returns the chain, the seconds GICP took and the number of
    frames on which it converged."""
    keyframes = np.asarray(saved["keyframes"])
    points, valid = np.asarray(clouds.points), np.asarray(clouds.valid)
    frames = len(keyframes)
    motions = np.tile(np.eye(4), (frames, 1, 1))  # keyframe → k
    chained = np.tile(np.eye(4), (frames, 1, 1))  # 0 → k
    converged, finite = np.ones(frames, bool), np.ones(frames, bool)
    seconds = 0.0
    for k in range(1, frames):
        j = keyframes[k]
        same_key = keyframes[k - 1] == j and k - 1 != j and finite[k - 1]
        init = motions[k - 1] if same_key else np.eye(4)
        t0 = time.perf_counter()
        motions[k], converged[k], finite[k] = gicp_align(points[j][valid[j]], points[k][valid[k]], init)
        seconds += time.perf_counter() - t0
        chained[k] = motions[k] @ chained[j] if finite[k] else chained[k - 1]
    origin = np.asarray(saved["points"][0])
    R, t = chained[:, :3, :3], chained[:, :3, 3]
    f32 = functools.partial(jnp.asarray, dtype=jnp.float32)
    chain = Chain(
        rotations=f32(R),
        translations=f32(t),
        points=f32(np.einsum("kij,j->ki", R, origin) + t),
        status=jnp.asarray(np.where(finite, SUCCESS, NOT_CONVERGED), jnp.int32),
        origin=f32(origin),
        relative_rotations=f32(motions[:, :3, :3]),
        relative_translations=f32(motions[:, :3, 3]),
        relative_cov=f32(jaxpose_covariances(saved)),
        switched=jnp.asarray(switched_at(keyframes)),
        continuity=jnp.zeros(frames, bool),
    )
    return chain, seconds, int(converged[1:].sum())


def relative_errors(chain: Chain, truth: np.ndarray, keyframes: np.ndarray) -> np.ndarray:
    """Rotation errors (°) of a chain's measurements keyframe → k against the truth."""
    true_rel = np.einsum("kij,klj->kil", truth, truth[keyframes])
    return np.degrees(np.asarray(jp.rotation_angle(chain.relative_rotations, jnp.asarray(true_rel, jnp.float32))))


def against_gicp(name: str = "tracking_benchmark") -> None:
    """The saved run `name`'s tumbles with a peer tracker: GICP's registrations through the
    same keyframes and filter (`gicp_chain`, `filter_keyframes` with its defaults) →
    `<name>_gicp.{json,md}`; each row also holds jaxpose's errors from the saved run and both
    chains' median registration error keyframe → k over the frames each registered."""
    benchmark, saved = saved_tumbles(name)
    duration, rate_hz = benchmark["duration_s"], benchmark["rate_hz"]
    run = jax.jit(lambda chain: filter_keyframes(chain, 1 / rate_hz))
    rows = []
    for row, tumble_saved in zip(benchmark["rows"], saved, strict=True):
        _, _, tumble, key = draw_tumble(row["tumble"], BENCHMARK_SEEDS)
        seq = simulate_tumble(row["family"], row["sigma_cm"], tumble, key, duration, rate_hz)
        clouds = jax.block_until_ready(seq.clouds)
        chain, seconds, converged = gicp_chain(clouds, tumble_saved)
        truth = np.asarray(seq.rotations)
        keyframes = np.asarray(tumble_saved["keyframes"])
        ours = chain_of_track(tumble_saved)
        ours_ok = np.array(is_registered(ours.status, ours.continuity))
        gicp_ok = np.asarray(chain.status) == SUCCESS
        ours_ok[0] = gicp_ok[0] = False
        out = {
            **{k: row[k] for k in ("tumble", "family", "sigma_cm", "camera", "rate_deg_s")},
            **filter_errors(run(chain), truth, rate_hz),
            "jaxpose_rate_error_deg_s": row["rate_error_deg_s"],
            "jaxpose_attitude_error_deg": row["attitude_error_deg"],
            "registration_error_median_deg": float(np.median(relative_errors(chain, truth, keyframes)[gicp_ok])),
            "jaxpose_registration_error_median_deg": float(np.median(relative_errors(ours, truth, keyframes)[ours_ok])),
            "gicp_converged": converged,
            "ms_per_frame": 1000 * seconds / (len(truth) - 1),
            "jaxpose_ms_per_frame": row["ms_per_frame"],
        }
        print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()}, flush=True)
        rows.append(out)
    write(rows, len(rows), duration, rate_hz, f"{name}_gicp")


def gicp_table(base: str = "tracking_benchmark") -> None:
    """jaxpose's chain and the GICP peer tracker on the same tumbles: the rows of the peer's
    runs on the draws of the run `base` (`<base>_gicp`, `<base>_from20_gicp`, written by
    `against_gicp`; and the third, `<base>_from40_gicp`, where it exists) →
    `tracking_gicp[<suffix>].{json,md}` (the suffix: what `base` adds to
    "tracking_benchmark", e.g. "_guided"): per noise level and over all, the rate error at the end
    (median / p90 / max, °/s), the attitude error at the end (median, °), on how many tumbles
    the peer's rate error is the smaller, the median registration error keyframe → k (median
    over the tumbles of each tumble's median, °) and the median time a frame (ms); beside them,
    where `<base>[_from20]_model` exist (`against_model`), the rate error of the same tumbles
    tracked against the body-frame model."""
    third = f"{base}_from40_gicp"
    runs = (f"{base}_gicp", f"{base}_from20_gicp") + ((third,) if (RESULTS / f"{third}.json").exists() else ())
    rows = [row for name in runs for row in json.loads((RESULTS / f"{name}.json").read_text())["rows"]]
    model_files = [RESULTS / f"{base}{draw}_model.json" for draw in ("", "_from20")]
    with_model = all(f.exists() for f in model_files)
    if with_model:
        models = {r["tumble"]: r for f in model_files for r in json.loads(f.read_text())["rows"]}
        rows = [{**r, "model_rate_error_deg_s": models[r["tumble"]]["rate_error_deg_s"]} for r in rows]
    levels = {f"{s:g}": [r for r in rows if r["sigma_cm"] == s] for s in NOISE_CM} | {"all": rows}
    out = []
    for level, group in levels.items():
        if not group:
            continue
        entry = {"sigma_cm": level, "tumbles": len(group)}
        for who, prefix in (("jaxpose", "jaxpose_"), ("gicp", "")):
            rate = np.array([r[f"{prefix}rate_error_deg_s"] for r in group])
            entry[who] = {
                "rate": {name: float(np.quantile(rate, q)) for name, q in QUANTILES.items()},
                "attitude_median": float(np.median([r[f"{prefix}attitude_error_deg"] for r in group])),
                "registration_median": float(np.median([r[f"{prefix}registration_error_median_deg"] for r in group])),
                "ms_per_frame_median": float(np.median([r[f"{prefix}ms_per_frame"] for r in group])),
            }
        entry["gicp_better"] = sum(r["rate_error_deg_s"] < r["jaxpose_rate_error_deg_s"] for r in group)
        if with_model:
            model = np.array([r["model_rate_error_deg_s"] for r in group])
            entry["model_rate"] = {name: float(np.quantile(model, q)) for name, q in QUANTILES.items()}
            entry["gicp_better_than_model"] = sum(r["rate_error_deg_s"] < r["model_rate_error_deg_s"] for r in group)
        out.append(entry)
    model_head = " jaxpose against the model | GICP smaller on |" if with_model else ""
    head = (
        f"| σ, cm | tumbles | rate error at the end, °/s: jaxpose | GICP | GICP smaller on |{model_head} attitude, °: "
        "jaxpose / GICP | registration error, °: jaxpose / GICP | ms a frame: jaxpose / GICP |\n"
        f"|---|---|---|---|---|{'---|---|' if with_model else ''}---|---|---|\n"
    )

    def model_cells(e):
        return f" {cell(e['model_rate'])} | {e['gicp_better_than_model']} |" if with_model else ""

    lines = [
        f"| {e['sigma_cm']} | {e['tumbles']} | {cell(e['jaxpose']['rate'])} | {cell(e['gicp']['rate'])} | "
        f"{e['gicp_better']} |{model_cells(e)} "
        f"{e['jaxpose']['attitude_median']:.3f} / {e['gicp']['attitude_median']:.3f} | "
        f"{e['jaxpose']['registration_median']:.3f} / {e['gicp']['registration_median']:.3f} | "
        f"{e['jaxpose']['ms_per_frame_median']:.0f} / {e['gicp']['ms_per_frame_median']:.0f} |"
        for e in out
    ]
    table = head + "\n".join(lines) + "\n"
    print(table)
    name = "tracking_gicp" + base.removeprefix("tracking_benchmark")
    write_json(f"{name}.json", {"runs": list(runs), "levels": out})
    (RESULTS / f"{name}.md").write_text(table)


def with_covariance(chain: Chain, scale: float, floor_deg: float) -> Chain:
    """`chain` with every measurement covariance times `scale` and (floor_deg, in radians)²
    added to its rotation block (rad², frame c)."""
    floor = jnp.diag(jnp.asarray([np.radians(floor_deg) ** 2] * 3 + [0.0] * 3, chain.relative_cov.dtype))
    return eqx.tree_at(lambda c: c.relative_cov, chain, chain.relative_cov * scale + floor)


def sweep(name: str = "tracking_benchmark", *more: str) -> None:
    """The saved registrations of a run (`name`: the last default run, or e.g.
    `tracking_issue_case`; with `more`, those runs' tumbles pooled with its own) through
    `filter_keyframes` with each of `SWEEP`'s settings → `tracking_refilter_sweep.{json,md}`
    (`<name>_refilter_sweep.*` for another run): per setting, the rate error at the end (°/s:
    median, p90, max over the tumbles) and the median attitude error (°)."""
    benchmark, tumbles = saved_tumbles(name)
    for other in more:
        tumbles += saved_tumbles(other)[1]
    rate_hz = benchmark["rate_hz"]
    rows = []
    modifiers = ("floor_deg", "cov_scale")
    for setting in SWEEP:
        options = {k: v for k, v in setting.items() if k not in modifiers}
        errors = refiltered(tumbles, rate_hz, options, setting.get("floor_deg", 0.0), setting.get("cov_scale", 1.0))
        rate = np.array([e["rate_error_deg_s"] for e in errors])
        attitude = np.array([e["attitude_error_deg"] for e in errors])
        rows.append(
            {
                "setting": setting,
                "rate_error_deg_s": {
                    "median": float(np.median(rate)),
                    "p90": float(np.percentile(rate, 90)),
                    "max": float(rate.max()),
                },
                "attitude_error_deg_median": float(np.median(attitude)),
                "non_finite": int(sum(e["non_finite"] for e in errors)),
            }
        )
    lines = [
        f"The registrations of `{', '.join((name, *more))}` ({len(tumbles)} tumbles) filtered again, "
        "one setting moved at a time.",
        "",
        "| setting | rate error at the end, °/s: median / p90 / max | attitude error median, ° | non-finite |",
        "|---|---|---|---|",
    ]
    for r in rows:
        label = ", ".join(f"{k}={v}" for k, v in r["setting"].items()) or "default"
        e = r["rate_error_deg_s"]
        rate = f"{e['median']:.3f} / {e['p90']:.3f} / {e['max']:.3f}"
        lines.append(f"| {label} | {rate} | {r['attitude_error_deg_median']:.3f} | {r['non_finite']} |")
    table = "\n".join(lines) + "\n"
    print(table)
    out = derived_name(name, "refilter_sweep")
    write_json(f"{out}.json", {"source": name, "rows": rows})
    (RESULTS / f"{out}.md").write_text(table)


REACH_BINS_DEG = (0, 2, 4, 6, 8, 10, 12, 15, 20, 30, 180)
"""Bins (°) of the true rotation keyframe → frame for `reach`."""


def reach(tumbles: int = 10, duration: float = 10.0, rate_hz: float = 25.0) -> None:
    """Register every frame of `tumbles` random tumbles (the benchmark's families and noise
    levels in turn, seeds 3000 + i) against frame 0 alone (`chain_estimates` with no keyframe
    switch) and tabulate, per bin of the true rotation from frame 0 (`REACH_BINS_DEG`):
    frames, the share whose estimate is a success, the share accepted by continuity, the
    median and 90th-percentile rotation error of the successes (°), the successes more than
    1° off, and the true motion of frame 0's plane origin (cm) → `tracking_reach.{json,md}`."""
    frames = []
    for index in range(tumbles):
        family, sigma, tumble, key = draw_tumble(index, REACH_SEEDS)
        seq = simulate_tumble(family, sigma, tumble, key, duration, rate_hz)
        config = sized_sequence_config(seq.clouds, jp.Config())
        steps = int(seq.rotations.shape[0])
        chain = _reach_program(seq.clouds, config, jax.random.fold_in(key, 2), steps)
        R = np.asarray(seq.rotations)
        true_rel = np.einsum("kij,lj->kil", R, R[0])
        angle = np.degrees(np.asarray(jp.rotation_angle(jnp.asarray(true_rel), jnp.eye(3))))
        error = np.degrees(np.asarray(jp.rotation_angle(chain.relative_rotations, jnp.asarray(true_rel))))
        status, continuity = np.asarray(chain.status), np.asarray(chain.continuity)
        origin, positions = np.asarray(chain.origin), np.asarray(seq.positions)
        shift = np.linalg.norm(true_rel @ (origin - positions[0]) + positions - origin, axis=1)
        for k in range(1, steps):
            frames.append((family, sigma, angle[k], int(status[k]), bool(continuity[k]), float(error[k]), shift[k]))
        print(
            index,
            family,
            sigma,
            f"{float(np.degrees(np.linalg.norm(np.asarray(tumble.rate)))):.2f} °/s",
            f"reach {angle.max():.1f}°, successes {int(np.sum(status[1:] == 0))}/{steps - 1}",
            flush=True,
        )
    rows = []
    for lo, hi in zip(REACH_BINS_DEG[:-1], REACH_BINS_DEG[1:], strict=True):
        inside = [f for f in frames if lo <= f[2] < hi]
        if not inside:
            continue
        success = [f for f in inside if f[3] == 0]
        errors = np.array([f[5] for f in success])
        rows.append(
            {
                "bin_deg": [lo, hi],
                "frames": len(inside),
                "success_share": len(success) / len(inside),
                "continuity_share": sum(f[4] for f in inside) / len(inside),
                "error_median_deg": float(np.median(errors)) if len(errors) else None,
                "error_p90_deg": float(np.quantile(errors, 0.9)) if len(errors) else None,
                "successes_over_1deg": int(np.sum(errors > 1.0)),
                "origin_shift_median_cm": float(100 * np.median([f[6] for f in inside])),
                "origin_shift_max_cm": float(100 * max(f[6] for f in inside)),
            }
        )
    fmt = lambda v: "–" if v is None else f"{v:.3f}"  # noqa: E731
    table = (
        "| rotation from the keyframe, ° | frames | success | accepted by continuity "
        "| error median / p90, ° | successes > 1° | origin shift median / max, cm |\n"
    )
    table += (
        "|---|---|---|---|---|---|---|\n"
        + "\n".join(
            f"| {r['bin_deg'][0]}–{r['bin_deg'][1]} | {r['frames']} | {r['success_share']:.2f} | "
            f"{r['continuity_share']:.2f} | {fmt(r['error_median_deg'])} / {fmt(r['error_p90_deg'])} | "
            f"{r['successes_over_1deg']} | {r['origin_shift_median_cm']:.1f} / {r['origin_shift_max_cm']:.1f} |"
            for r in rows
        )
        + "\n"
    )
    print(table)
    write_json("tracking_reach.json", {"tumbles": tumbles, "duration_s": duration, "rate_hz": rate_hz, "bins": rows})
    (RESULTS / "tracking_reach.md").write_text(table)


@functools.partial(jax.jit, static_argnums=(1, 3))
def _reach_program(clouds, config, key, steps):
    """`chain_estimates` against frame 0 alone (no switch within `steps` frames)."""
    return chain_estimates(clouds, config, key, keyframe_every=steps, keyframe_reach=None)


def by_family(rows: list[dict]) -> dict[str, list[dict]]:
    """The rows of each family of `FAMILIES` that has any, in that order, then "all" rows."""
    groups = {f: [r for r in rows if r["family"] == f] for f in FAMILIES} | {"all": rows}
    return {name: group for name, group in groups.items() if group}


def summarise(rows: list[dict]) -> list[dict]:
    out = []
    for name, group in by_family(rows).items():
        rate = np.array([r["rate_error_deg_s"] for r in group])
        att = np.array([r["attitude_error_deg"] for r in group])
        out.append(
            {
                "family": name,
                "tumbles": len(group),
                "rate_error_median": float(np.median(rate)),
                "rate_error_p90": float(np.quantile(rate, 0.9)),
                "rate_error_max": float(rate.max()),
                "attitude_error_median": float(np.median(att)),
                "attitude_error_max": float(att.max()),
                "registered": f"{sum(r['registered'] - 1 for r in group)}/{sum(r['frames'] - 1 for r in group)}",
                "by_continuity": sum(r.get("by_continuity", 0) for r in group),
                "fused": f"{sum(r['fused'] - 1 for r in group)}/{sum(r['frames'] - 1 for r in group)}",
                "non_finite": sum(r["non_finite"] for r in group),
                "ms_per_frame_median": float(np.median([r["ms_per_frame"] for r in group])),
            }
        )
    return out


def markdown(summary: list[dict], duration: float) -> str:
    head = (
        f"| family | tumbles | rate error at {duration:g} s, °/s: median / p90 / max | attitude error, °: median / max "
        "| frames registered (by continuity) | fused | non-finite | ms per frame |\n|---|---|---|---|---|---|---|---|\n"
    )
    rows = [
        f"| {s['family']} | {s['tumbles']} | {s['rate_error_median']:.3f} / {s['rate_error_p90']:.3f} / "
        f"{s['rate_error_max']:.3f} | {s['attitude_error_median']:.3f} / {s['attitude_error_max']:.3f} | "
        f"{s['registered']} ({s['by_continuity']}) | {s['fused']} | {s['non_finite']} | "
        f"{s['ms_per_frame_median']:.0f} |"
        for s in summary
    ]
    return head + "\n".join(rows) + "\n"


def write(rows: list[dict], tumbles: int, duration: float, rate_hz: float, name: str = "tracking_benchmark") -> None:
    summary = summarise(rows)
    table = markdown(summary, duration)
    print(table)
    payload = {"tumbles": tumbles, "duration_s": duration, "rate_hz": rate_hz, "summary": summary, "rows": rows}
    write_json(f"{name}.json", payload)
    (RESULTS / f"{name}.md").write_text(table)


def resummarise() -> None:
    saved = json.loads((RESULTS / "tracking_benchmark.json").read_text())
    write(saved["rows"], saved["tumbles"], saved["duration_s"], saved["rate_hz"])


def issue_case(runs: int = 3, duration: float = 10.0, rate_hz: float = 25.0) -> None:
    """Issue 25's own case (`issue_tumble`, σ = 1 cm) with `runs` independent noise draws →
    `tracking_issue_case.{json,md}` (registrations in `tracking_issue_case_chains.npz`), each
    run tracked again against the body-frame model (`model_row`) →
    `tracking_issue_case_model.{json,md}`, and each run's registrations through `identify`
    (`identified_row`) → `tracking_issue_case_identified.{json,md}`."""
    rows, models, identified_rows = [], [], []
    for run in range(runs):
        key = jax.random.key(2000 + run)
        row = run_tumble(run, "n5", 1.0, issue_tumble(), key, duration, rate_hz)
        rows.append(row)
        print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
        models.append(model_row(row, SAVED[-1], issue_tumble(), key, duration, rate_hz))
        identified_rows.append(identified_row(row, SAVED[-1], issue_tumble(), rate_hz))
    write(rows, runs, duration, rate_hz, "tracking_issue_case")
    write(models, runs, duration, rate_hz, "tracking_issue_case_model")
    write_identified(identified_rows, duration, "tracking_issue_case")
    stacked = {field: np.stack([s[field] for s in SAVED]) for field in SAVED[0]}
    np.savez_compressed(RESULTS / "tracking_issue_case_chains.npz", **stacked)


def main(
    tumbles: int = 20, duration: float = 10.0, rate_hz: float = 25.0, mode: str = "default", first: int = 0
) -> None:
    """`mode`: one of `MODES`; other modes than the default are written to
    `tracking_benchmark_<mode>.*`. `first`: the index of the first tumble (`one_tumble`); a
    draw that does not start at 0 is written with the suffix `_from<first>`."""
    rows = []
    for index in range(first, first + tumbles):
        row = one_tumble(index, duration, rate_hz, MODES[mode])
        rows.append(row)
        print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    suffix = ("" if mode == "default" else f"_{mode}") + ("" if first == 0 else f"_from{first}")
    write(rows, tumbles, duration, rate_hz, "tracking_benchmark" + suffix)
    stacked = {field: np.stack([s[field] for s in SAVED]) for field in SAVED[0]}
    np.savez_compressed(RESULTS / f"tracking_benchmark{suffix}_chains.npz", **stacked)


if __name__ == "__main__":
    if sys.argv[1:] == ["summarise"]:
        resummarise()
    elif sys.argv[1:2] == ["registrations"]:
        registration_errors(*sys.argv[2:3])
    elif sys.argv[1:2] == ["refilter"]:
        refilter(json.loads(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "options")
    elif sys.argv[1:2] == ["sweep"]:
        sweep(*sys.argv[2:])
    elif sys.argv[1:2] == ["identified"]:
        identified(*sys.argv[2:3])
    elif sys.argv[1:2] == ["model"]:
        against_model(*sys.argv[2:3])
    elif sys.argv[1:2] == ["gicp"]:
        against_gicp(*sys.argv[2:3])
    elif sys.argv[1:2] == ["gicp_table"]:
        gicp_table(*sys.argv[2:3])
    elif sys.argv[1:2] == ["reach"]:
        reach(*(f(a) for f, a in zip((int, float, float), sys.argv[2:], strict=False)))
    elif sys.argv[1:2] == ["issue"]:
        issue_case(*(int(a) for a in sys.argv[2:3]))
    else:
        main(*(f(a) for f, a in zip((int, float, float, str, int), sys.argv[1:], strict=False)))
