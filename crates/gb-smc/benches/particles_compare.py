"""Time the Python `particles` library (Chopin) on the model of the Rust bench
`bootstrap_ar1/10000` (crates/gb-smc/benches/filter.rs):

    x_t = 0.9 x_{t-1} + N(0, 1),  y_t = x_t + N(0, 0.5^2),
    N = 10 000 particles, T = 1000, systematic resampling at every step,
    log-likelihood computed.

Usage: python3 -m pip install particles==0.4 && python3 crates/gb-smc/benches/particles_compare.py
Prints the median wall time of a full filter run and the throughput in
particle-steps per second.
"""
import statistics
import sys
import time

import importlib.metadata

import numpy as np
import particles
from particles import distributions as dists
from particles import state_space_models as ssm

N = 10_000
T = 1000
REPS = int(sys.argv[1]) if len(sys.argv) > 1 else 7

phi, sx, sy = 0.9, 1.0, 0.5


class AR1(ssm.StateSpaceModel):
    """x_0 ~ N(0, sx^2 / (1 - phi^2)), x_t = phi x_{t-1} + N(0, sx^2), y_t = x_t + N(0, sy^2)."""

    default_params = {"phi": phi, "sx": sx, "sy": sy}

    def PX0(self):
        return dists.Normal(loc=0.0, scale=self.sx / np.sqrt(1.0 - self.phi**2))

    def PX(self, t, xp):
        return dists.Normal(loc=self.phi * xp, scale=self.sx)

    def PY(self, t, xp, x):
        return dists.Normal(loc=x, scale=self.sy)


model = AR1()
np.random.seed(1)
_, y = model.simulate(T)

times = []
ll = None
for r in range(REPS):
    fk = ssm.Bootstrap(ssm=model, data=y)
    # ESSrmin=1: resample whenever ESS < N, i.e. at every step
    alg = particles.SMC(fk=fk, N=N, resampling="systematic", ESSrmin=1.0,
                        store_history=False, collect=None, verbose=False)
    t0 = time.perf_counter()
    alg.run()
    times.append(time.perf_counter() - t0)
    ll = alg.logLt

med = statistics.median(times)
print(f"particles {importlib.metadata.version('particles')}: bootstrap_ar1/{N}, T={T}")
print(f"median time per run: {med * 1e3:.1f} ms over {REPS} runs (min {min(times) * 1e3:.1f} ms)")
print(f"throughput: {N * T / med / 1e6:.2f} M particle-steps/s")
print(f"log-likelihood (last run): {ll:.3f}")
