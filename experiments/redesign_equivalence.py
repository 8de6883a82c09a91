"""Same results before and after a refactor: run this script in two checkouts and compare
the JSON files (issue 20's before/after check; it uses only names both layouts have, the
deprecated flat Config keywords included).

- the paper's four pairs × `Config()`, `Config.paper()`, `Config.fast()`, key 0: status and p;
- the first `count` capture pairs (`capture_pair(i, seed=0)`, 5–45°) with `Config.wide()`;
- a 2 s N5 tumble (4.5 °/s, 1 cm range noise) through `track` with `Config.fast()`.

    uv run python experiments/redesign_equivalence.py OUT.json [count]
    python experiments/redesign_equivalence.py --compare A.json B.json
"""

from __future__ import annotations

import json
import sys
import time
import warnings

import numpy as np


def run(out: str, count: int = 10) -> None:
    warnings.simplefilter("ignore", DeprecationWarning)
    import jax

    import jaxpose as jp

    try:
        from jaxpose.sim import Tumble, capture_pair, paper_pairs, simulate_sequence
    except ImportError:  # the flat layout before the redesign
        from jaxpose.scenarios import capture_pair, paper_pairs
        from jaxpose.sequence import Tumble, simulate_sequence
    result = {"paper": {}, "capture": {}}
    for pair in paper_pairs():
        for name, config in (("default", None), ("paper", jp.Config.paper()), ("fast", jp.Config.fast())):
            est = jp.estimate(pair.prev, pair.curr, config, key=jax.random.key(0))
            result["paper"][f"{pair.label} {name}"] = [int(est.status), *map(float, est.params)]
    wide = jp.Config.wide(max_points=10240, max_cells=1024, grid_cells=160)
    start = time.perf_counter()
    for i in range(count):
        pair = capture_pair(i, seed=0)
        est = jp.estimate(pair.prev, pair.curr, wide, key=jax.random.key(i))
        error = float(np.degrees(jp.rotation_angle(est.rotation, pair.motion[0])))
        result["capture"][str(i)] = [int(est.status), error, *map(float, est.params)]
    result["capture_s"] = time.perf_counter() - start
    camera = jp.Camera.camcube2(noise_sigma=0.01)
    seq = simulate_sequence(camera, jp.targets.n5(), Tumble.n5(4.5), duration=2.0, key=jax.random.key(0))
    start = time.perf_counter()
    track = jp.track(seq.clouds, 0.04, jp.Config.fast(max_points=5120), key=jax.random.key(0))
    result["track_s"] = time.perf_counter() - start
    result["track"] = {
        "rate_end": [float(x) for x in track.rate[-1]],
        "attitude_end": np.asarray(track.attitude[-1]).tolist(),
        "status": [int(x) for x in track.status],
    }
    with open(out, "w") as f:
        json.dump(result, f, indent=1)


def compare(a: str, b: str) -> None:
    with open(a) as fa, open(b) as fb:
        before, after = json.load(fa), json.load(fb)
    for part in ("paper", "capture"):
        worst = max(max(abs(x - y) for x, y in zip(before[part][k], after[part][k], strict=True)) for k in before[part])
        found = [sum(v[1] < 1.0 for v in r[part].values()) for r in (before, after)] if part == "capture" else ""
        print(f"{part}: {len(before[part])} results, largest |difference| {worst:.3g}", found)
    t_before, t_after = before["track"], after["track"]
    rate = max(abs(x - y) for x, y in zip(t_before["rate_end"], t_after["rate_end"], strict=True))
    attitude = np.max(np.abs(np.array(t_before["attitude_end"]) - np.array(t_after["attitude_end"])))
    same_status = t_before["status"] == t_after["status"]
    print(f"track: rate |difference| {rate:.3g}, attitude {attitude:.3g}, statuses equal {same_status}")
    capture_s, track_s = (before["capture_s"], after["capture_s"]), (before["track_s"], after["track_s"])
    print(f"times: capture {capture_s[0]:.0f} → {capture_s[1]:.0f} s, track {track_s[0]:.1f} → {track_s[1]:.1f} s")


if __name__ == "__main__":
    if sys.argv[1] == "--compare":
        compare(sys.argv[2], sys.argv[3])
    else:
        run(sys.argv[1], *(int(a) for a in sys.argv[2:]))
