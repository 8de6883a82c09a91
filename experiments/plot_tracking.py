"""Figures of the tracking results (issue 7), from the committed registrations and JSON.

- `results/tumble_tracking.png`: angular-rate error per frame on the N5 tumble (4.5 °/s,
  25 Hz, 1 cm noise) for both noise seeds, three filters re-run on the saved registrations
  (`results/tumble_chain.npz`, `results/tumble_chain_seed1.npz`, written by
  `experiments/tumble_tracking.py`); the truth comes from the same dynamics (no rendering).
- `results/chibis_m.png`: Chibis-M rotation and centre error against range
  (`results/chibis_m.json`, written by `experiments/chibis_m.py`).

    uv run python experiments/plot_tracking.py
"""

import json

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
from _common import RESULTS
from tumble_tracking import FILTERS, load_chain, true_rates

from jaxpose.evaluation.figures import save_figure
from jaxpose.sim import Tumble, tumble_poses

RATE_HZ = 25.0
# Legend label → the experiment's filter of that name.
PLOTTED = {
    "chained, constant rate": "chained, constant rate",
    "chained, constant α": "chained, constant acceleration",
    "keyframe clone, half shared (default)": "keyframe clone, half shared (default)",
}


def tumble_figure():
    fig, axes = plt.subplots(1, 2, figsize=(12, 4), sharey=True)
    for ax, (seed, name) in zip(axes, ((0, "tumble_chain.npz"), (1, "tumble_chain_seed1.npz")), strict=True):
        chain = load_chain(RESULTS / name)
        times = jnp.arange(chain.status.shape[0]) / RATE_HZ
        R = np.asarray(tumble_poses(Tumble.n5(4.5), times)[0])
        truth = true_rates(R, RATE_HZ)
        for label, name in PLOTTED.items():
            method, options = FILTERS[name]
            rate = np.asarray(jax.jit(lambda ch, f=method, o=options: f(ch, 1 / RATE_HZ, **o))(chain).rate)
            ax.plot(np.asarray(times), np.degrees(np.linalg.norm(rate - truth, axis=1)), label=label)
        ax.axhline(0.05, color="k", ls="--", lw=0.8, label="goal 0.05 °/s")
        ax.set(yscale="log", ylim=(5e-3, 5), xlabel="time, s", title=f"noise seed {seed}")
    axes[0].set_ylabel("angular-rate error, °/s")
    axes[0].legend()
    save_figure(fig, RESULTS / "tumble_tracking.png", title="N5 tumbling at 4.5 °/s, 1 cm range noise, 25 Hz")


def chibis_figure():
    data = json.loads((RESULTS / "chibis_m.json").read_text())
    rows = data["pairs"]
    r = np.array([row["range_m"] for row in rows])
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, key, label in (
        (axes[0], "rotation_error_deg", "rotation error of the 1 s motion, °"),
        (axes[1], "centre_error_cm", "centre position error, cm"),
    ):
        values = np.array([row[key] for row in rows])
        ok = np.array([row["status"] == 0 for row in rows])
        ax.scatter(r[ok], values[ok], label="status success")
        ax.scatter(r[~ok], values[~ok], marker="x", label="other status")
        ax.set(yscale="log", xlabel="range, m", ylabel=label)
    axes[0].legend()
    save_figure(fig, RESULTS / "chibis_m.png", title="Chibis-M-like target, 1 cm range noise, 5 pairs per range")


if __name__ == "__main__":
    tumble_figure()
    chibis_figure()
    print("wrote results/tumble_tracking.png, results/chibis_m.png")
