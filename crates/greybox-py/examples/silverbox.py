"""Diagnose the Silverbox benchmark (an electronic Duffing oscillator) from
Python and plot measured vs simulated output on the multisine test record.

    python crates/greybox-py/examples/silverbox.py [DATA_DIR] [PLOT.png]

DATA_DIR defaults to $GREYBOX_DATA, else ../shared/data (run from the
repository root); the plot goes to docs/img/python-example.png.
"""
import os
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import greybox  # noqa: E402

data_dir = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("GREYBOX_DATA", "../shared/data"))
out = Path(sys.argv[2] if len(sys.argv) > 2 else "docs/img/python-example.png")

# u = input voltage V1, y = output voltage V2 [V]; fs = 610.35 Hz
train = np.loadtxt(data_dir / "silverbox" / "train_multisine.csv", delimiter=",", skiprows=1)
test = np.loadtxt(data_dir / "silverbox" / "test_multisine.csv", delimiter=",", skiprows=1)
u, y = train[:20000, 0], train[:20000, 1]  # the first 20000 training samples
u_test, y_test = test[:, 0], test[:, 1]

t0 = time.perf_counter()
d = greybox.diagnose(u, y, u_test, y_test)
print(d.to_text())
print(f"{d!r}  ({time.perf_counter() - t0:.1f} s)")

# the benchmark's convention: the first 50 test samples initialise the state
n0 = 50
final = d.final_model
linear = greybox.fit(u, y, "linear", order=2)
sims = {"linear OE, order 2": linear.simulate(u_test, init=y_test[:n0]), "diagnosed model": final.simulate(u_test, init=y_test[:n0])}
rmse = {k: 1e3 * np.sqrt(np.mean((y_test[n0:] - s[n0:]) ** 2)) for k, s in sims.items()}
for k, r in rmse.items():
    print(f"{k}: test RMSE {r:.3f} mV")

k = np.arange(len(y_test))
# zoom on the linear model's worst error (the large amplitudes)
worst = n0 + int(np.argmax(np.abs(y_test[n0:] - sims["linear OE, order 2"][n0:])))
zoom = slice(max(worst - 80, n0), worst + 80)
fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 6), constrained_layout=True)
a1.plot(k[zoom], 1e3 * y_test[zoom], color="black", lw=2.0, label="measured")
colors = {"linear OE, order 2": "tab:blue", "diagnosed model": "tab:red"}
for name, s in sims.items():
    a1.plot(k[zoom], 1e3 * s[zoom], color=colors[name], lw=1.0, label=f"{name} (free run)")
a1.set_ylabel("y [mV]")
a1.set_title(f"Silverbox multisine test, samples {zoom.start}..{zoom.stop} (the linear model's worst) — diagnose names: {', '.join(d.causes) or 'none'}", fontsize=10)
a1.legend(loc="upper right", fontsize=8)
for name, s in sims.items():
    a2.plot(k[n0:], 1e3 * (y_test[n0:] - s[n0:]), color=colors[name], lw=0.5, label=f"{name}: RMSE {rmse[name]:.2f} mV")
a2.set_xlabel("sample")
a2.set_ylabel("error y − y_sim [mV]")
a2.set_title("simulation error over the whole test record (after the 50-sample init window)", fontsize=10)
a2.legend(loc="upper left", fontsize=8)
out.parent.mkdir(parents=True, exist_ok=True)
fig.savefig(out, dpi=100)
print(f"plot written to {out}")
