"""Frame-to-model registration against the keyframe chain on the tumbles of `identify.py` (issue 24).

For each case of the last `identify.py` run (its tracks in `results/identify_tracks.npz`), the
clouds are simulated again with the same keys (the very clouds the tracker registered) and
every frame is registered against the growing body-frame model with
`jp.track_against_model`, from the saved chain. Reported per case, against the true motions:

- the attitude error of the measured motion first frame → k (°): at the last frame (60 s),
  its largest over the run and its median, for the keyframe chain and for the model; and the
  filtered attitude's error at the last frame for both;
- the frames registered against the model;
- `jp.identify` on both tracks: the inertia ratios' relative errors (%), the principal axes'
  errors (°), the centre of mass's error (cm), `observable`;
- the time of `track_against_model`, compile included (one process).

    uv run python experiments/model_tracking.py [case ...]  →  results/model_tracking.{json,md}
    uv run python experiments/model_tracking.py refit       →  the identify columns again

`refit` runs `jp.identify` again on both saved tracks of the last run (the chain's in
`identify_tracks.npz`, the model's in `model_tracking_tracks.npz`) and rewrites the tables
with the registration columns, their seconds and machine kept from the last run's JSON (the
refit's machine under `refit_machine`): what an `identify` change needs, without tracking.

The model's tracks (each frame's motion, registration flag and covariance) go to
`results/model_tracking_tracks.npz` (with the cases' names in the file names when only some
run), in the layout of `identify_tracks.npz`.
"""

from __future__ import annotations

import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from _common import RESULTS, machine, write_json
from identify import CASES, DISTANCE, make_tumble

import jaxpose as jp
from jaxpose._estimate import NOT_CONVERGED, SUCCESS
from jaxpose.sim import simulate_sequence
from jaxpose.sim._sequence import tumble_poses


def saved_track(saved, case: str) -> jp.Track:
    """The chain of the `identify.py` run as a `Track` of its measurements (the filtered fields
    are not saved; `track_against_model` and `identify` read the measurements alone)."""

    def get(name):
        return jnp.asarray(saved[f"{case}/{name}"])

    return jp.Track.of_measurements(
        get("rotations"),
        get("points"),
        get("keyframes"),
        get("measurement_cov"),
        status=jnp.where(get("registered"), SUCCESS, NOT_CONVERGED),
    )


def angle_deg(R: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    """Angle (°) of R R_trueᵀ per frame, in float64 (float32's arccos floors at 0.05°)."""
    M = np.einsum("kij,klj->kil", np.asarray(R, np.float64), np.asarray(R_true, np.float64))
    skew = np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]], axis=1)
    return np.degrees(np.arctan2(np.linalg.norm(skew, axis=1), np.trace(M, axis1=1, axis2=2) - 1))


def dynamics_errors(dyn, saved, case: str) -> dict:
    axes, ratios = saved[f"{case}/true_axes"], saved[f"{case}/true_ratios"]
    cosines = np.abs(np.sum(np.asarray(dyn.principal_axes) * axes, axis=0))
    return {
        "ratio_error_pct": (100 * (np.asarray(dyn.inertia_ratios) / ratios - 1)).tolist(),
        "axis_error_deg": np.degrees(np.arccos(np.clip(cosines, -1, 1))).tolist(),
        "centre_error_cm": 100 * float(np.linalg.norm(np.asarray(dyn.centre) - saved[f"{case}/true_centre"])),
        "observable": bool(dyn.observable),
    }


def one_case(saved, case: str) -> dict:
    index = CASES.index(case)
    dt = float(saved["dt"])
    T = saved[f"{case}/rotations"].shape[0]
    key = jax.random.key(2000 + index)
    family = "n5" if case.startswith("n5") else case
    tumble = make_tumble(case, jax.random.fold_in(key, 0))
    camera = jp.Camera.camcube2(noise_sigma=0.01, noise_range_ref=5.0)
    seq = simulate_sequence(
        camera, getattr(jp.targets, family)(), tumble, (T - 1) * dt, 1 / dt, key=jax.random.fold_in(key, 1)
    )
    clouds = jax.block_until_ready(seq.clouds)
    chain = saved_track(saved, case)
    t0 = time.perf_counter()
    model = jax.block_until_ready(jp.track_against_model(clouds, chain, dt))
    seconds = time.perf_counter() - t0

    G = np.asarray(tumble_poses(tumble, seq.times)[0], np.float64)
    true_R = np.einsum("kij,lj->kil", G, G[0])
    chain_err, model_err = angle_deg(chain.rotations, true_R), angle_deg(model.rotations, true_R)
    row = {
        "case": case,
        "frames": int(T),
        "keyframes": int(np.unique(np.asarray(chain.keyframes)).size),
        "registered_model": int(np.sum(np.asarray(model.registered()))),
        "registered_chain": int(np.sum(np.asarray(chain.registered()))),
        "chain_deg": [float(chain_err[-1]), float(chain_err.max()), float(np.median(chain_err))],
        "model_deg": [float(model_err[-1]), float(model_err.max()), float(np.median(model_err))],
        "model_filtered_end_deg": float(angle_deg(model.attitude, true_R)[-1]),
        "identify_chain": dynamics_errors(jp.identify(chain, dt), saved, case),
        "identify_model": dynamics_errors(jp.identify(model, dt), saved, case),
        "seconds": seconds,
    }
    print(row, flush=True)
    saved_model = {
        "rotations": model.rotations,
        "points": model.points,
        "keyframes": model.keyframes,
        "registered": model.registered(),
        "measurement_cov": model.measurement_cov,
    }
    return row, {f"{case}/{name}": np.asarray(value) for name, value in saved_model.items()}


def markdown(rows: list[dict], duration: float, rate_hz: float) -> str:
    def triple(v):
        return " / ".join(f"{x:.3f}" for x in v)

    def dyn(d):
        ratios = ", ".join(f"{e:+.2f}" for e in d["ratio_error_pct"])
        axes = ", ".join(f"{a:.1f}" for a in d["axis_error_deg"])
        return f"{ratios} / {axes} / {d['centre_error_cm']:.2f} / {d['observable']}"

    head = (
        f"{duration:g} s at {rate_hz:g} Hz, 1 cm range noise, {DISTANCE:g} m, inertial camera (the `identify.py` "
        "tumbles). Attitude error of the measured motion first frame → k, °: at the last frame / largest / median. "
        "identify: ratio errors % / axis errors ° / centre cm / observable.\n\n"
        "| case | frames registered: chain / model | keyframe chain, ° | against the model, ° | "
        "identify, chain | identify, model | model s |\n"
        "|---|---|---|---|---|---|---|\n"
    )
    lines = [
        f"| {r['case']} | {r['registered_chain']} / {r['registered_model']} of {r['frames']} | "
        f"{triple(r['chain_deg'])} | {triple(r['model_deg'])} | {dyn(r['identify_chain'])} | "
        f"{dyn(r['identify_model'])} | {r['seconds']:.0f} |"
        for r in rows
    ]
    return head + "\n".join(lines) + "\n"


def refit(cases=CASES):
    """`identify` again on the last run's saved tracks, chain and model (see the module)."""
    saved, models = np.load(RESULTS / "identify_tracks.npz"), np.load(RESULTS / "model_tracking_tracks.npz")
    last = json.loads((RESULTS / "model_tracking.json").read_text())
    dt = float(saved["dt"])
    rows = [row for row in last["rows"] if row["case"] in cases]
    for row in rows:
        case = row["case"]
        row["identify_chain"] = dynamics_errors(jp.identify(saved_track(saved, case), dt), saved, case)
        row["identify_model"] = dynamics_errors(jp.identify(saved_track(models, case), dt), saved, case)
        print(row, flush=True)
    duration = (saved[f"{cases[0]}/rotations"].shape[0] - 1) * dt
    text = markdown(rows, duration, 1 / dt)
    print(text)
    (RESULTS / "model_tracking.md").write_text(text)
    (RESULTS / "model_tracking.json").write_text(
        json.dumps({"machine": last["machine"], "refit_machine": machine(), "rows": rows}, indent=2)
    )


def main(cases=CASES):
    saved = np.load(RESULTS / "identify_tracks.npz")
    results = [one_case(saved, case) for case in cases]
    rows = [row for row, _ in results]
    dt = float(saved["dt"])
    duration = (saved[f"{cases[0]}/rotations"].shape[0] - 1) * dt
    text = markdown(rows, duration, 1 / dt)
    print(text)
    suffix = "" if tuple(cases) == CASES else "_" + "_".join(cases)
    (RESULTS / f"model_tracking{suffix}.md").write_text(text)
    write_json(f"model_tracking{suffix}.json", {"rows": rows})
    tracks = {"dt": np.asarray(dt)} | {k: v for _, arrays in results for k, v in arrays.items()}
    np.savez_compressed(RESULTS / f"model_tracking{suffix}_tracks.npz", **tracks)


if __name__ == "__main__":
    if sys.argv[1:2] == ["refit"]:
        refit()
    else:
        main(tuple(sys.argv[1:]) or CASES)
