"""Where the fine stage's plane goes through: the point or its neighbourhood's centroid.

N5 tumbling at 4.5 °/s at 5.5 m (as `experiments/tumble_tracking.py`), 1 cm range noise.
Four keyframes (t = 0, 1, 2, 3 s); each is registered with `Config.tracking()` to the
frames 2, 6, …, 22 after it (0.4–4° of motion). Reported per setting: the RMS rotation
error of the registrations (°, per camera axis) and the slope of the error against the
time since the keyframe (°/s, mean over the keyframes): a slope is a bias of the angular
rate that the filter of `jaxpose.track` would read from these registrations.

Noise is put in both clouds, or only in the keyframe's ("previous"), or only in the
current one, to show which side the bias comes from.

Second part (`views`): the default preset with either anchor on the noise-free random
views of `experiments/bench_estimate.py` (`capture_pair(i, seed=1, 3°, 20°)`, i < 16, one
refused for its grid), scored by bench_estimate's `random_views`: found, successes, statuses.

    uv run python experiments/fine_anchor.py        →  results/fine_anchor.json
    uv run python experiments/fine_anchor.py views  →  results/fine_anchor_views.json
"""

import sys
import time

import jax
import jaxlie
import numpy as np
from _common import write_json
from bench_estimate import random_views

import jaxpose as jp
from jaxpose.sim import Tumble, simulate_sequence

KEYFRAMES = (0, 25, 50, 75)
OFFSETS = (2, 6, 10, 14, 18, 22)


def registration_errors(config, prev_seq, curr_seq, R):
    """Rotation errors (°, rotation vector in frame c) of every keyframe → keyframe + offset."""
    run = jax.jit(lambda a, b, key: jp.estimate(a, b, config, key=key))
    errors = np.zeros((len(KEYFRAMES), len(OFFSETS), 3))
    for i, key_frame in enumerate(KEYFRAMES):
        prev = jax.tree.map(lambda x, f=key_frame: x[f], prev_seq.clouds)
        for j, offset in enumerate(OFFSETS):
            k = key_frame + offset
            est = run(prev, jax.tree.map(lambda x, k=k: x[k], curr_seq.clouds), jax.random.key(k))
            wrong = np.asarray(est.rotation) @ (R[k] @ R[key_frame].T).T
            errors[i, j] = np.degrees(np.asarray(jaxlie.SO3.from_matrix(wrong).log()))
    return errors


def main():
    duration = KEYFRAMES[-1] / 25 + 1
    noisy = simulate_sequence(
        jp.Camera.camcube2(noise_sigma=0.01), jp.targets.n5(), Tumble.n5(4.5), duration, key=jax.random.key(11)
    )
    clean = simulate_sequence(jp.Camera.camcube2(noise_sigma=0.0), jp.targets.n5(), Tumble.n5(4.5), duration)
    R = np.asarray(noisy.rotations)
    sides = {"both": (noisy, noisy), "previous": (noisy, clean), "current": (clean, noisy)}
    rows = []
    for anchor in ("point", "centroid"):
        config = jp.Config.tracking(max_points=6144, fine_anchor=anchor)
        for side, (prev_seq, curr_seq) in sides.items():
            t0 = time.perf_counter()
            errors = registration_errors(config, prev_seq, curr_seq, R)
            t = np.asarray(OFFSETS) / 25
            slopes = np.array([[np.polyfit(t, e[:, a], 1)[0] for a in range(3)] for e in errors])
            row = {
                "anchor": anchor,
                "noise_in": side,
                "rms_error_deg": np.sqrt(np.mean(errors**2, axis=(0, 1))).round(4).tolist(),
                "slope_deg_s_mean": slopes.mean(0).round(4).tolist(),
                "slope_deg_s_per_keyframe": slopes.round(4).tolist(),
                "seconds_incl_compile": round(time.perf_counter() - t0, 1),  # not a benchmark
            }
            print(row, flush=True)
            rows.append(row)
    write_json("fine_anchor.json", {"rate_deg_s": 4.5, "range_noise_m": 0.01, "rows": rows})


def views():
    """The default preset with either anchor on bench_estimate's noise-free random views."""
    out = {}
    for anchor in ("point", "centroid"):
        config = jp.Config.accurate(max_points=8192, max_prev_points=8192, fine_anchor=anchor)
        out[anchor] = random_views(anchor, config)
    write_json("fine_anchor_views.json", out)


if __name__ == "__main__":
    views() if sys.argv[1:] == ["views"] else main()
