"""Dynamics identified from tracked tumbles (issue 24): `jp.track` then `jp.identify`.

Each case is a torque-free tumble seen by a camera that holds an inertial attitude, 6 m away.
The target's shape gives the clouds and the tumble's inertia gives the motion: N5, the
satellite and the upper stage with random inertia ratios, axis and rate (`Tumble.random`, 3–6
°/s), and Chibis-M with the report's J = diag(1.60, 1.16, 1.86) kg·m² at 4.5 °/s about the
report's axis. Range noise σ = 1 cm (ToF, growing with range), `duration` seconds at
`rate_hz`, `jp.track(clouds, dt, key=...)` with the default config.

Reported per case:

- the inertia ratios' relative errors (%), the principal axes' angle errors (°), the centre
  of mass's error (cm), the `observable` flag and the ratios' standard deviations;
- the prediction `horizon` seconds past the data of the target's farthest point from the
  centre (its edge), from `Dynamics.predict_point` and from constant-rate extrapolation of
  the filter's last state (attitude, rate, tracked point's position and velocity), in cm;
- time: tracking and identification, compile included (one process, one run).

A fifth case spins N5 about a principal axis: `observable` must be False.

    uv run python experiments/identify.py [duration_s] [rate_hz] [horizon_s]  →  results/identify.{json,md}
    uv run python experiments/identify.py orbital [duration_s] [rate_hz] [horizon_s]  →  results/identify_orbital.*
    uv run python experiments/identify.py issue [runs] [duration_s] [rate_hz] [horizon_s]
        →  results/identify_issue_case.*  (issue 25's own N5 tumble, moments 1 : 1.4 : 1.9,
        `runs` noise draws; `ISSUE_CASE`; identify_issue_case_<duration>s.* for another window)

The tracks (each frame's chained motion, keyframe, registration flag and covariance) and the
true motions go to `results/identify_tracks.npz`, so that `identify` can be studied again
without tracking (`uv run python experiments/identify.py refit` → `results/identify_refit.{json,md}`).
`uv run python experiments/identify.py perturb [case]` → `results/identify_perturb.{json,md}`
refits one case's saved tracks with its rotations scaled by 1 + ε (round-off sized).
`uv run python experiments/identify.py synthetic [sigma_deg]` → `results/identify_synthetic.{json,md}`
fits the true motions with white rotation noise, each frame measured from the first
(`synthetic`).
"""

from __future__ import annotations

import json
import math
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from _common import RESULTS, write_json
from tracking_benchmark import issue_tumble

import jaxpose as jp
from jaxpose.sim import Tumble, simulate_sequence
from jaxpose.sim._sequence import C_FROM_O, tumble_poses
from jaxpose.sim.targets import CHIBIS_M_INERTIA
from jaxpose.tracking import _identify
from jaxpose.tracking._identify import identify_tracked
from jaxpose.tracking._track import chained_motions

CASES = ("n5", "chibis_m", "satellite", "upper_stage", "n5_principal_spin")
ORBITAL_CASES = ("n5_orbital", "chibis_m_orbital")
"""Cases seen from a chaser whose camera is fixed in the orbital frame of a 500 km orbit
(gravity-gradient torque; `identify(..., orbit=...)`): `identify.py orbital ...`."""
DISTANCE = 6.0
ISSUE_CASE = "n5_issue25"
"""Issue 25's own tumble (`tracking_benchmark.issue_tumble`: N5 with principal moments
1 : 1.4 : 1.9, 4.5 °/s about a non-principal axis, 5.5 m away), for `identify.py issue`: its
moments lie far apart, where N5's random ones in `CASES` lie within 3 %."""


def make_tumble(case: str, key) -> Tumble:
    if case == ISSUE_CASE:
        return issue_tumble()
    orbital = case.endswith("_orbital")
    base = Tumble.random(key, distance=DISTANCE, rates_deg_s=(3.0, 6.0), orbital_camera=orbital)
    case = case.removesuffix("_orbital")
    if case == "chibis_m":
        axis = jnp.array([2.08, 3.01, 2.15])
        rate = math.radians(4.5) * axis / jnp.linalg.norm(axis)
        base = eqx.tree_at(lambda t: (t.rate, t.inertia), base, (rate, jnp.diag(jnp.asarray(CHIBIS_M_INERTIA))))
    if case == "n5_principal_spin":
        base = eqx.tree_at(lambda t: t.rate, base, jnp.array([0.0, 0.0, math.radians(4.5)]))
    return base


def case_tumble(case: str, index: int) -> Tumble:
    """Case `case`'s tumble drawn from the keys of `index` (as every run of this script draws it)."""
    return make_tumble(case, jax.random.fold_in(jax.random.key(2000 + index), 0))


def truth(tumble: Tumble, times):
    G, positions, rates = tumble_poses(tumble, times)
    moments = np.diag(np.asarray(tumble.inertia))
    order = np.argsort(moments)
    axes = np.asarray(G[0])[:, order]
    return G, positions, axes, moments[order] / moments[order][2], np.asarray(G[0] @ rates[0])


def edge_point(cloud: jp.Cloud, centre: np.ndarray) -> np.ndarray:
    """The first cloud's valid point farthest from the centre of mass (m, frame c)."""
    pts = np.asarray(cloud.points)[np.asarray(cloud.valid)]
    return pts[np.argmax(np.linalg.norm(pts - centre[None], axis=1))]


def edge_prediction(first: jp.Cloud, G, positions, dyn: jp.Dynamics, end: float):
    """The first cloud's edge point (`edge_point`, m, frame c at t = 0), where it truly is at
    time `end` (s since the first frame), and where `dyn.predict_point` puts it, with that
    prediction's standard deviations (m, frame c). `G`, `positions`: the true attitudes and
    centres at times (0, `end`) (`truth`)."""
    centre = np.asarray(positions[0])
    point = edge_point(first, centre)
    R_end = np.asarray(G[1]) @ np.asarray(G[0]).T
    true_point = R_end @ (point - centre) + np.asarray(positions[1])
    predicted, std = dyn.predict_point(jnp.asarray(point), jnp.asarray([end]))
    return point, true_point, np.asarray(predicted[0]), np.asarray(std[0])


def constant_rate(track: jp.Track, point: np.ndarray, horizon: float, dt: float) -> np.ndarray:
    """Where constant-rate extrapolation of the filter's last state puts `point` (frame c at
    t = 0) `horizon` seconds past the last frame."""
    A, w = np.asarray(track.attitude[-1]), np.asarray(track.rate[-1])
    p, v = np.asarray(track.position[-1]), np.asarray(track.velocity[-1])
    p0 = np.asarray(track.points[0])
    now = A @ (point - p0) + p  # the point at the last frame, carried by the filtered motion
    turn = np.asarray(jaxlie.SO3.exp(jnp.asarray(w * horizon)).as_matrix())
    return turn @ (now - p) + p + v * horizon


def simulated(case: str, index: int, duration: float, rate_hz: float):
    """Case `case`'s tumble and its simulated sequence, from the keys of `index`."""
    key = jax.random.key(2000 + index)
    family = "n5" if case.startswith("n5") else case.removesuffix("_orbital")
    target = getattr(jp.targets, family)()
    tumble = case_tumble(case, index)
    camera = jp.Camera.camcube2(noise_sigma=0.01, noise_range_ref=5.0)
    return tumble, simulate_sequence(camera, target, tumble, duration, rate_hz, key=jax.random.fold_in(key, 1))


def one_case(case: str, index: int, duration: float, rate_hz: float, horizon: float) -> dict:
    key = jax.random.key(2000 + index)
    tumble, seq = simulated(case, index, duration, rate_hz)
    clouds = jax.block_until_ready(seq.clouds)
    dt = 1 / rate_hz
    t0 = time.perf_counter()
    track = jax.block_until_ready(jp.track(clouds, dt, key=jax.random.fold_in(key, 2)))
    track_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    orbit = jp.Orbit(jnp.asarray(tumble.orbit_rate), C_FROM_O) if case.endswith("_orbital") else None
    dyn = jax.block_until_ready(jp.identify(track, dt, orbit=orbit))
    identify_s = time.perf_counter() - t0

    end = float(seq.times[-1]) + horizon
    G, positions, axes, moments, omega = truth(tumble, jnp.asarray([0.0, end]))
    centre = np.asarray(positions[0])
    first = jax.tree.map(lambda x: x[0], clouds)
    point, true_point, predicted, std = edge_prediction(first, G, positions, dyn, end)
    extrapolated = constant_rate(track, point, horizon, dt)
    cosines = np.abs(np.sum(np.asarray(dyn.principal_axes) * axes, axis=0))
    ratio_std = np.sqrt(np.diag(np.asarray(dyn.covariance)))[3:5]
    row = {
        "case": case,
        "rate_deg_s": float(np.degrees(np.linalg.norm(np.asarray(tumble.rate)))),
        "true_ratios": moments[:2].tolist(),
        "ratios": np.asarray(dyn.inertia_ratios).tolist(),
        "ratio_error_pct": (100 * (np.asarray(dyn.inertia_ratios) / moments[:2] - 1)).tolist(),
        "ratio_std": ratio_std.tolist(),
        "axis_error_deg": np.degrees(np.arccos(np.clip(cosines, -1, 1))).tolist(),
        "centre_error_cm": 100 * float(np.linalg.norm(np.asarray(dyn.centre) - centre)),
        "omega_error_deg_s": float(np.degrees(np.linalg.norm(np.asarray(dyn.omega) - omega))),
        "observable": bool(dyn.observable),
        "excitation_deg": float(np.degrees(dyn.excitation)),
        "rotation_rms_deg": float(np.degrees(dyn.rotation_rms)),
        "frames_used": int(dyn.frames),
        "frames": int(seq.times.shape[0]),
        "edge_distance_m": float(np.linalg.norm(point - centre)),
        "prediction_error_cm": 100 * float(np.linalg.norm(predicted - true_point)),
        "prediction_std_cm": (100 * std).tolist(),
        "constant_rate_error_cm": 100 * float(np.linalg.norm(extrapolated - true_point)),
        "track_s": track_s,
        "identify_s": identify_s,
    }
    print({k: (np.round(v, 4).tolist() if isinstance(v, list) else v) for k, v in row.items()}, flush=True)
    saved = {
        "rotations": track.rotations,
        "points": track.points,
        "keyframes": track.keyframes,
        "registered": track.registered(),
        "measurement_cov": track.measurement_cov,
        "true_attitudes": tumble_poses(tumble, seq.times)[0],
        "true_axes": truth(tumble, seq.times[:1])[2],
        "true_ratios": jnp.asarray(moments[:2]),
        "true_centre": jnp.asarray(centre),
    }
    return row, {f"{case}/{name}": np.asarray(value) for name, value in saved.items()}


def markdown(rows: list[dict], duration: float, rate_hz: float, horizon: float) -> str:
    head = (
        f"{duration:g} s at {rate_hz:g} Hz, 1 cm range noise, inertial camera, torque-free; prediction "
        f"{horizon:g} s past the data.\n\n"
        "| case | rate °/s | ratio errors % (σ) | axis errors ° | centre cm | observable | "
        "edge point at +{h} s: identified / constant rate, cm | track s | identify s |\n"
        "|---|---|---|---|---|---|---|---|---|\n"
    ).replace("{h}", f"{horizon:g}")
    lines = []
    for r in rows:
        triples = zip(r["ratio_error_pct"], r["ratio_std"], r["true_ratios"], strict=True)
        ratio = ", ".join(f"{e:+.2f} ({100 * s / t:.2f})" for e, s, t in triples)
        axes = ", ".join(f"{a:.2f}" for a in r["axis_error_deg"])
        lines.append(
            f"| {r['case']} | {r['rate_deg_s']:.2f} | {ratio} | {axes} | {r['centre_error_cm']:.2f} | "
            f"{r['observable']} | {r['prediction_error_cm']:.2f} / {r['constant_rate_error_cm']:.2f} | "
            f"{r['track_s']:.0f} | {r['identify_s']:.1f} |"
        )
    return head + "\n".join(lines) + "\n"


def listed(values) -> str:
    """Numbers as one markdown cell: "a, b, c"."""
    return ", ".join(f"{v:g}" for v in values)


def write_table(name: str, head: str, lines: list[str], payload: dict) -> None:
    """`results/{name}.md` (`head`, then one table row per line) and `results/{name}.json`."""
    (RESULTS / f"{name}.md").write_text(head + "\n".join(lines) + "\n")
    write_json(f"{name}.json", payload)


def fit_costs(get, dt: float, dyn: jp.Dynamics, tumble: Tumble) -> tuple[float, float]:
    """[`costs_at_fit_and_truth`][] on a saved track's arrays (`get(name)`), with the truth
    of `tumble`. A truth that costs less than the fit means the search missed the minimum;
    one that costs as much means the data do not tell the two apart."""
    rotations = jnp.asarray(get("rotations"))
    T = rotations.shape[0]
    references = jnp.asarray(get("keyframes"), jnp.int32)
    _, finite = chained_motions(rotations, jnp.asarray(get("points"), rotations.dtype))
    used = _identify.used_frames(jnp.asarray(get("registered"), bool) & finite, references)
    whiten = _identify._whitening(jnp.asarray(get("measurement_cov"), rotations.dtype)[:, :3, :3], used)
    times = jnp.arange(T, dtype=rotations.dtype) * dt
    _, _, axes, ratios, omega = truth(tumble, jnp.zeros(1))
    return costs_at_fit_and_truth(dyn, (axes, ratios, omega), times, rotations, used, references, whiten)


def costs_at_fit_and_truth(dyn, true, times, rotations, used, references, whiten) -> tuple[float, float]:
    """The least-squares cost that `identify` minimises (whitened attitude residuals of the
    motions reference → frame, decorrelated for the keyframes' shared error) at the fitted
    dynamics `dyn` and at the true ones, `true` = (principal axes, ratios, first rate) as
    `truth` gives them; both decorrelated with the ratio ρ of the fit's residuals, as
    `identify` decorrelates its last fit."""
    dtype = rotations.dtype

    def residuals(axes, ratios, omega):
        moments = jnp.concatenate([jnp.asarray(ratios, dtype), jnp.ones(1, dtype)])
        data = (times, rotations, used, references, whiten, jnp.asarray(axes, dtype), moments, jp.Orbit.inertial())
        theta = jnp.concatenate([jnp.zeros(5, dtype), jnp.asarray(omega, dtype)])
        return _identify._rotation_residuals(theta, data)

    axes, ratios, omega = true
    fitted = residuals(dyn.principal_axes, dyn.inertia_ratios, dyn.omega)
    at_truth = residuals(_identify._right_handed(jnp.asarray(axes)), ratios[:2], omega)
    rho = _identify.shared_variance_ratio(fitted, used, references)
    cost = lambda r: float(jnp.sum(_identify.decorrelated(r, used, references, rho) ** 2))  # noqa: E731
    return cost(fitted), cost(at_truth)


def refit(**options) -> list[dict]:
    """`identify` again on the tracks saved by the last run (`results/identify_tracks.npz`),
    with `identify_tracked`'s `options`: the ratios' relative errors (%), the axes' errors (°),
    the centre's error (cm) and, per camera axis, the centre's error and standard deviation
    (cm) and their ratio (z), the edge point's prediction error `horizon_s` past the data (cm;
    the first cloud simulated again from the run's keys), and the fit's and the truth's
    least-squares costs (`fit_costs`) per case → `results/identify_refit.{json,md}`."""
    saved = np.load(RESULTS / "identify_tracks.npz")
    run = json.loads((RESULTS / "identify.json").read_text())
    duration, rate_hz, horizon = run["duration_s"], run["rate_hz"], run["horizon_s"]
    rows = []
    for index, case in enumerate(CASES):

        def get(name, case=case):
            return saved[f"{case}/{name}"]

        dyn = identify_tracked(
            get("rotations"),
            get("points"),
            get("registered"),
            get("keyframes"),
            get("measurement_cov"),
            float(saved["dt"]),
            **options,
        )
        axes = get("true_axes")
        cosines = np.abs(np.sum(np.asarray(dyn.principal_axes) * axes, axis=0))
        centre_error = 100 * (np.asarray(dyn.centre) - get("true_centre"))
        centre_std = 100 * np.sqrt(np.diag(np.asarray(dyn.covariance))[8:11])
        tumble, seq = simulated(case, index, duration, rate_hz)
        cost_fit, cost_truth = fit_costs(get, float(saved["dt"]), dyn, tumble)
        first = jax.tree.map(lambda x: x[0], seq.clouds)
        end = float(seq.times[-1]) + horizon
        G, positions, *_ = truth(tumble, jnp.asarray([0.0, end]))
        point, true_point, predicted, _ = edge_prediction(first, G, positions, dyn, end)
        rows.append(
            {
                "case": case,
                "ratio_error_pct": (100 * (np.asarray(dyn.inertia_ratios) / get("true_ratios") - 1))
                .astype(float)
                .round(2)
                .tolist(),
                "axis_error_deg": np.degrees(np.arccos(np.clip(cosines, -1, 1))).astype(float).round(2).tolist(),
                "centre_error_cm": round(100 * float(np.linalg.norm(np.asarray(dyn.centre) - get("true_centre"))), 2),
                "centre_axis_error_cm": centre_error.astype(float).round(2).tolist(),
                "centre_std_cm": centre_std.astype(float).round(2).tolist(),
                "centre_z": (np.abs(centre_error) / centre_std).astype(float).round(1).tolist(),
                "observable": bool(dyn.observable),
                "prediction_error_cm": round(100 * float(np.linalg.norm(predicted - true_point)), 2),
                "edge_distance_m": float(np.linalg.norm(point - get("true_centre"))),
                "cost_fit": round(cost_fit, 1),
                "cost_truth": round(cost_truth, 1),
                "residuals": 3 * int(dyn.frames),
            }
        )
        print(rows[-1], flush=True)
    head = (
        "`identify` on the tracks of `results/identify_tracks.npz` (`identify.py refit`). Centre of mass per camera "
        "axis: error / standard deviation, cm, and |error| / std. Cost: the least-squares cost that `identify` "
        "minimises (whitened residuals, decorrelated with the fit's shared-error ratio) at the fit and at the true "
        "dynamics, over that many residuals. Edge point: the first cloud's point farthest from the centre, predicted "
        "`horizon_s` past the data (the clouds simulated again from the run's keys).\n\n"
        "| case | ratio errors % | axis errors ° | centre cm | centre error, cm | centre std, cm | z | observable | "
        f"edge point at +{horizon:g} s, cm | cost: fit / truth (residuals) |\n"
        "|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = [
        f"| {r['case']} | {listed(r['ratio_error_pct'])} | {listed(r['axis_error_deg'])} | {r['centre_error_cm']:g} | "
        f"{listed(r['centre_axis_error_cm'])} | {listed(r['centre_std_cm'])} | {listed(r['centre_z'])} | "
        f"{r['observable']} | {r['prediction_error_cm']:.2f} | {r['cost_fit']:.0f} / {r['cost_truth']:.0f} "
        f"({r['residuals']}) |"
        for r in rows
    ]
    write_table("identify_refit", head, lines, {"rows": rows})
    return rows


PERTURBATIONS = (0.0, 1e-7, -1e-7, 3e-7)
"""`perturb`'s relative scalings of the saved rotations: round-off-sized changes of the data."""


def perturb(case: str = "chibis_m") -> list[dict]:
    """`identify` on one case's saved tracks (`results/identify_tracks.npz`) with the rotations
    scaled by 1 + ε for each ε of `PERTURBATIONS`: the ratios' relative errors and standard
    deviations (%) and the fit's and the truth's least-squares costs (`fit_costs`), so how far
    round-off moves the fit along the cost's valley → `results/identify_perturb.{json,md}`."""
    saved = np.load(RESULTS / "identify_tracks.npz")
    index = CASES.index(case)
    tumble = case_tumble(case, index)
    rows = []
    for eps in PERTURBATIONS:

        def get(name, eps=eps):
            value = saved[f"{case}/{name}"]
            return value * (1 + eps) if name == "rotations" else value

        fields = ("rotations", "points", "registered", "keyframes", "measurement_cov")
        dyn = identify_tracked(*(get(n) for n in fields), float(saved["dt"]))
        cost_fit, cost_truth = fit_costs(get, float(saved["dt"]), dyn, tumble)
        true = get("true_ratios")
        rows.append(
            {
                "case": case,
                "epsilon": eps,
                "ratio_error_pct": (100 * (np.asarray(dyn.inertia_ratios, float) / true - 1)).round(2).tolist(),
                "ratio_std_pct": (100 * np.sqrt(np.diag(np.asarray(dyn.covariance, float)))[3:5] / true)
                .round(2)
                .tolist(),
                "cost_fit": round(cost_fit, 1),
                "cost_truth": round(cost_truth, 1),
            }
        )
        print(rows[-1], flush=True)
    head = (
        f"`identify` on {case}'s saved tracks with the rotations scaled by 1 + ε (`identify.py perturb {case}`).\n\n"
        "| ε | ratio errors % | ratio std % | cost: fit / truth |\n|---|---|---|---|\n"
    )
    lines = [
        f"| {r['epsilon']:g} | {listed(r['ratio_error_pct'])} | {listed(r['ratio_std_pct'])} | "
        f"{r['cost_fit']:.1f} / {r['cost_truth']:.1f} |"
        for r in rows
    ]
    write_table("identify_perturb", head, lines, {"rows": rows})
    return rows


def synthetic_row(case: str, index: int, times, noise_vectors: np.ndarray, first: str) -> dict:
    """One case of `synthetic`: the true motions turned by `noise_vectors` (T, 3) (rad), the
    first frame's set to zero where `first` is "exact"."""
    T = times.shape[0]
    tumble = case_tumble(case, index)
    G, _, axes, ratios, omega = truth(tumble, times)
    vectors = jnp.asarray(noise_vectors, jnp.float32)
    vectors = vectors.at[0].set(0.0) if first == "exact" else vectors
    noise = jax.vmap(lambda v: jaxlie.SO3.exp(v).as_matrix())(vectors)
    motions = jnp.asarray(np.asarray(G) @ np.asarray(G[0]).T, jnp.float32)
    rotations = jnp.einsum("tij,tjk->tik", noise, motions)
    valid, references = jnp.ones(T, bool), jnp.zeros(T, jnp.int32)
    dyn = _identify.identify_motion(times, rotations, jnp.zeros((T, 3), jnp.float32), valid)
    used = _identify.used_frames(valid, references)
    whiten = jnp.broadcast_to(jnp.eye(3, dtype=jnp.float32) / _identify.RESIDUAL_UNIT, (T, 3, 3))
    true = (axes, ratios, omega)
    cost_fit, cost_truth = costs_at_fit_and_truth(dyn, true, times, rotations, used, references, whiten)
    cosines = np.abs(np.sum(np.asarray(dyn.principal_axes) * axes, axis=0))
    return {
        "case": case,
        "first_frame": first,
        "ratio_error_pct": (100 * (np.asarray(dyn.inertia_ratios) / ratios[:2] - 1)).astype(float).round(2).tolist(),
        "axis_error_deg": np.degrees(np.arccos(np.clip(cosines, -1, 1))).astype(float).round(2).tolist(),
        "cost_fit": round(cost_fit, 1),
        "cost_truth": round(cost_truth, 1),
        "cost_noise": round(float(jnp.sum(vectors[1:] ** 2)) / _identify.RESIDUAL_UNIT**2, 1),
        "residuals": 3 * (T - 1),
        "observable": bool(dyn.observable),
    }


def synthetic(sigma_deg: float = 0.2, duration: float = 60.0, rate_hz: float = 25.0, seed: int = 0) -> list[dict]:
    """`identify_motion` on the true motions of the tumbles about non-principal axes, each
    frame's rotation turned by white noise of `sigma_deg` per axis and measured from the
    first frame, equal weights; the first frame exact, then with its own noise, which every
    measurement then shares (as a track against a model shares the model's error). Per case:
    the ratios' relative errors (%), the axes' errors (°), `observable`, and the least-squares
    cost at the fit, at the true dynamics (`costs_at_fit_and_truth`) and of the noise alone (the
    exact motions with the first frame's error known) → `results/identify_synthetic.{json,md}`.
    It tests the fit apart from the registrations: a fit that costs far more than the noise
    alone is the search's failure."""
    rng = np.random.default_rng(seed)
    times = jnp.arange(int(round(duration * rate_hz)) + 1, dtype=jnp.float32) / rate_hz
    vectors = rng.normal(size=(len(CASES), times.shape[0], 3)) * math.radians(sigma_deg)
    rows = []
    for first in ("exact", "noisy"):
        for index, case in enumerate(CASES[:4]):
            rows.append(synthetic_row(case, index, times, vectors[index], first))
            print(rows[-1], flush=True)
    head = (
        f"`identify_motion` on the true motions of {duration:g} s at {rate_hz:g} Hz, each frame measured from "
        f"the first with {sigma_deg:g}° of white noise per axis (`identify.py synthetic`). Cost: the "
        "least-squares cost at the fit, at the true dynamics and of the noise alone, over that many residuals.\n\n"
        "| case | first frame | ratio errors % | axis errors ° | cost: fit / truth / noise (residuals) | observable |\n"
        "|---|---|---|---|---|---|\n"
    )
    lines = [
        f"| {r['case']} | {r['first_frame']} | {listed(r['ratio_error_pct'])} | {listed(r['axis_error_deg'])} | "
        f"{r['cost_fit']:.0f} / {r['cost_truth']:.0f} / {r['cost_noise']:.0f} ({r['residuals']}) | "
        f"{r['observable']} |"
        for r in rows
    ]
    payload = {"sigma_deg": sigma_deg, "duration_s": duration, "rate_hz": rate_hz, "seed": seed, "rows": rows}
    write_table("identify_synthetic", head, lines, payload)
    return rows


def main(duration: float = 60.0, rate_hz: float = 25.0, horizon: float = 10.0, cases=CASES, name="identify"):
    results = [one_case(case, i, duration, rate_hz, horizon) for i, case in enumerate(cases)]
    rows = [row for row, _ in results]
    np.savez_compressed(
        RESULTS / f"{name}_tracks.npz", dt=1 / rate_hz, **{k: v for _, arrays in results for k, v in arrays.items()}
    )
    text = markdown(rows, duration, rate_hz, horizon)
    if cases is ORBITAL_CASES:
        text = text.replace("inertial camera, torque-free", "camera fixed in the orbital frame, gravity gradient")
    print(text)
    (RESULTS / f"{name}.md").write_text(text)
    write_json(f"{name}.json", {"duration_s": duration, "rate_hz": rate_hz, "horizon_s": horizon, "rows": rows})


def issue(runs: int = 3, duration: float = 60.0, rate_hz: float = 25.0, horizon: float = 10.0) -> None:
    """Issue 25's tumble (`ISSUE_CASE`) with `runs` independent noise draws (the keys of
    indices 0 … runs − 1) → `results/identify_issue_case.{json,md}` and its tracks
    (`identify_issue_case_<duration>s.*` for a window other than 60 s)."""
    name = "identify_issue_case" if duration == 60.0 else f"identify_issue_case_{duration:g}s"
    results = [one_case(ISSUE_CASE, i, duration, rate_hz, horizon) for i in range(int(runs))]
    rows = [{**row, "case": f"{ISSUE_CASE} #{i}"} for i, (row, _) in enumerate(results)]
    arrays = {f"{i}/{k}": v for i, (_, saved) in enumerate(results) for k, v in saved.items()}
    np.savez_compressed(RESULTS / f"{name}_tracks.npz", dt=1 / rate_hz, **arrays)
    text = markdown(rows, duration, rate_hz, horizon)
    print(text)
    (RESULTS / f"{name}.md").write_text(text)
    payload = {"duration_s": duration, "rate_hz": rate_hz, "horizon_s": horizon, "rows": rows}
    write_json(f"{name}.json", payload)


if __name__ == "__main__":
    if sys.argv[1:2] == ["issue"]:
        issue(*(float(a) for a in sys.argv[2:6]))
    elif sys.argv[1:2] == ["refit"]:
        refit()
    elif sys.argv[1:2] == ["perturb"]:
        perturb(*sys.argv[2:3])
    elif sys.argv[1:2] == ["synthetic"]:
        synthetic(*(float(a) for a in sys.argv[2:3]))
    elif sys.argv[1:2] == ["orbital"]:
        main(*(float(a) for a in sys.argv[2:5]), cases=ORBITAL_CASES, name="identify_orbital")
    else:
        main(*(float(a) for a in sys.argv[1:4]))
