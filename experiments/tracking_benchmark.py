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

    uv run python experiments/tracking_benchmark.py [tumbles] [duration_s] [rate_hz] [guided]
        → results/tracking_benchmark[_guided].{json,md}
    uv run python experiments/tracking_benchmark.py summarise   (the table again from the JSON's rows)
    uv run python experiments/tracking_benchmark.py issue [runs]
        → results/tracking_issue_case.{json,md}: issue 25's own N5 case (`issue_tumble`)
"""

from __future__ import annotations

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
from jaxpose.sim import Tumble, simulate_sequence
from jaxpose.tracking._track import FILTER_UPDATED, _track_program

FAMILIES = ("n5", "chibis_m", "satellite", "upper_stage", "fragment")
NOISE_CM = (0.0, 0.5, 1.0, 2.0)
FILTERED = ("attitude", "rate", "spin_accel", "position", "velocity", "rate_std")


def true_rates(R: np.ndarray, rate_hz: float) -> np.ndarray:
    """Apparent angular velocity (rad/s, frame c) at each frame from consecutive true poses."""
    rate = np.stack([np.asarray(jaxlie.SO3.from_matrix(R[k + 1] @ R[k].T).log()) * rate_hz for k in range(len(R) - 1)])
    return np.concatenate([rate[:1], rate])


def one_tumble(index: int, duration: float, rate_hz: float, guided: bool = False) -> dict:
    family = FAMILIES[index % len(FAMILIES)]
    sigma = NOISE_CM[(index // len(FAMILIES)) % len(NOISE_CM)]
    orbital = bool(index % 2)
    key = jax.random.key(1000 + index)
    tumble = Tumble.random(jax.random.fold_in(key, 0), distance=6.0, orbital_camera=orbital)
    return run_tumble(index, family, sigma, tumble, key, duration, rate_hz, guided)


ISSUE_MOMENTS = (1.0, 1.4, 1.9)
"""Principal moments of the issue's own case (N5, torque-free, issue 25), relative."""


def issue_tumble() -> Tumble:
    """Issue 25's case: N5 5.5 m from a camera holding an inertial attitude, torque-free with
    principal moments 1 : 1.4 : 1.9, turning at 4.5 °/s about the non-principal body axis
    (1, 2, 3)/√14 (`Tumble.n5`'s), in the paper's previous attitude."""
    base = Tumble.n5(rate_deg_s=4.5, distance=5.5)
    inertia = jnp.diag(jnp.asarray(ISSUE_MOMENTS)) * 100.0
    return eqx.tree_at(lambda t: (t.inertia, t.orbit_rate), base, (inertia, 0.0))


def run_tumble(index, family, sigma, tumble, key, duration, rate_hz, guided=False) -> dict:
    """Simulate one tumble (range noise `sigma` cm at 5 m, growing with range), track it with
    the default config and measure it (see the module docstring)."""
    orbital = bool(tumble.orbit_rate)
    target = getattr(jp.targets, family)()
    camera = jp.Camera.camcube2(noise_sigma=sigma / 100, noise_range_ref=5.0)
    seq = simulate_sequence(camera, target, tumble, duration, rate_hz, key=jax.random.fold_in(key, 1))
    clouds = jax.block_until_ready(seq.clouds)
    _track_program.last_compile_s = 0.0
    t0 = time.perf_counter()
    result = jax.block_until_ready(jp.track(clouds, 1 / rate_hz, key=jax.random.fold_in(key, 2), guided=guided))
    seconds = time.perf_counter() - t0
    compile_s = _track_program.last_compile_s
    R = np.asarray(seq.rotations)
    truth_rate = true_rates(R, rate_hz)
    rate_err = np.degrees(np.linalg.norm(np.asarray(result.rate) - truth_rate, axis=1))
    truth_A = np.einsum("kij,lj->kil", R, R[0])
    attitude = np.degrees(float(jp.rotation_angle(result.attitude[-1], truth_A[-1])))
    every = int(rate_hz)
    frames = len(R)
    nonfinite = sum(int(np.sum(~np.isfinite(np.asarray(getattr(result, f))))) for f in FILTERED)
    return {
        "tumble": index,
        "family": family,
        "sigma_cm": sigma,
        "camera": "orbital" if orbital else "inertial",
        "rate_deg_s": float(np.degrees(np.linalg.norm(np.asarray(tumble.rate)))),
        "frames": frames,
        # Both count frame 0 (a success and the filter's start); the summary leaves it out.
        "registered": int(np.sum(np.asarray(result.registered()))),
        "by_continuity": int(np.sum(np.asarray(result.continuity))),
        "fused": int(np.sum(np.asarray(result.filter_status) == FILTER_UPDATED)),
        "non_finite": nonfinite,
        "rate_error_deg_s": float(rate_err[-1]),
        "rate_error_last_second_max_deg_s": float(rate_err[-every:].max()),
        "attitude_error_deg": attitude,
        "compile_s": compile_s,
        "ms_per_frame": 1000 * (seconds - compile_s) / (frames - 1),
    }


def summarise(rows: list[dict]) -> list[dict]:
    groups = {f: [r for r in rows if r["family"] == f] for f in FAMILIES} | {"all": rows}
    out = []
    for name, group in groups.items():
        if not group:
            continue
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
    `tracking_issue_case.{json,md}`."""
    rows = []
    for run in range(runs):
        row = run_tumble(run, "n5", 1.0, issue_tumble(), jax.random.key(2000 + run), duration, rate_hz)
        rows.append(row)
        print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    write(rows, runs, duration, rate_hz, "tracking_issue_case")


def main(tumbles: int = 20, duration: float = 10.0, rate_hz: float = 25.0, mode: str = "default") -> None:
    """`mode` "guided": `jp.track(..., guided=True)`, written to `tracking_benchmark_guided.*`."""
    guided = mode == "guided"
    rows = []
    for index in range(tumbles):
        row = one_tumble(index, duration, rate_hz, guided)
        rows.append(row)
        print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    write(rows, tumbles, duration, rate_hz, "tracking_benchmark_guided" if guided else "tracking_benchmark")


if __name__ == "__main__":
    if sys.argv[1:] == ["summarise"]:
        resummarise()
    elif sys.argv[1:2] == ["issue"]:
        issue_case(*(int(a) for a in sys.argv[2:3]))
    else:
        main(*(f(a) for f, a in zip((int, float, float, str), sys.argv[1:], strict=False)))
