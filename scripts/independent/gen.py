#!/usr/bin/env python3
"""Test systems written apart from gb_diagnose::generator (other code, other
conventions), to check the diagnosis on systems it was not tuned on:
a mass of 1 with f0 (0.5-3 Hz) and zeta (0.03-0.25) drawn, RK4 with 10
sub-steps under a zero-order-hold input, the output sampled at the start of
each held input; 12-50 samples per resonance period, 30-40 dB SNR,
8000 + 4000 samples (env NTR, NVA).

usage: gen.py FAMILY SEED OUTDIR  -> train.csv validate.csv meta.json
families: linear accel third-order duffing tanh-sensor input-sq in-sat
friction bouc-wen preisach-smooth backlash-in process ar-noise"""
import json, sys, os
import numpy as np

fam, seed, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
rng = np.random.default_rng(1000 + seed * 31 + sum(map(ord, fam)))
os.makedirs(out, exist_ok=True)
N_TR, N_VA = int(os.environ.get("NTR", 8000)), int(os.environ.get("NVA", 4000))
N = N_TR + N_VA

# plant: m q'' + c q' + k q + extra = g(u)
m = 1.0
f0 = rng.uniform(0.5, 3.0)  # Hz
w0 = 2 * np.pi * f0
zeta = rng.uniform(0.03, 0.25)
k = m * w0**2
c = 2 * zeta * w0 * m
spp = rng.uniform(12, 50)  # samples per resonance period
ts = 1.0 / (f0 * spp)
sub = 10
snr = rng.uniform(30, 40)


def excitation(n):
    kind = rng.choice(["multisine", "noise", "prbs", "sweep"])
    t = np.arange(n) * ts
    fmax = rng.uniform(1.5, 3.0) * f0
    if kind == "multisine":
        fs = np.linspace(0.02 * f0, fmax, 60)
        u = sum(np.cos(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in fs)
    elif kind == "noise":
        e = rng.standard_normal(n + 200)
        a = np.exp(-2 * np.pi * fmax * ts)
        u = np.zeros(n + 200)
        for i in range(1, n + 200):
            u[i] = a * u[i - 1] + e[i]
        u = u[200:]
    elif kind == "prbs":
        hold = max(1, int(round(1.0 / (fmax * ts * 2))))
        u = np.repeat(rng.choice([-1.0, 1.0], n // hold + 1), hold)[:n]
    else:
        # two repeated log sweeps
        T = n * ts / 2
        f1, f2 = 0.05 * f0, fmax
        tt = np.mod(t, T)
        u = np.sin(2 * np.pi * f1 * T / np.log(f2 / f1) * (np.exp(tt / T * np.log(f2 / f1)) - 1))
    u = u / np.std(u)
    # a binary input shows no input map: PRBS always gets the slow part
    if rng.uniform() < 0.5 or (kind == "prbs" and fam in ("input-sq", "in-sat", "backlash-in")):
        u = u + 0.8 * np.sin(2 * np.pi * 0.03 * f0 * t + rng.uniform(0, 6))
    return u, kind


u, kind = excitation(N)
expected = "none"
desc = ""

# effect parameters
eff = {}
if fam == "duffing":
    expected = "nonlinearity"
elif fam == "tanh-sensor":
    expected = "nonlinearity"
elif fam == "input-sq":
    expected = "nonlinearity"
elif fam == "friction":
    expected = "nonlinearity"
elif fam == "bouc-wen":
    expected = "hysteresis"
elif fam == "preisach-smooth":
    expected = "hysteresis"
elif fam == "backlash-in":
    expected = "hysteresis"
elif fam == "process":
    expected = "noise"
elif fam == "ar-noise":
    expected = "noise"
elif fam == "linear":
    expected = "none"
elif fam == "accel":
    expected = "none"
elif fam == "third-order":
    expected = "dynamics"
elif fam == "in-sat":
    expected = "nonlinearity"
else:
    raise SystemExit("unknown family")


def simulate(u, x_scale=None, eff=None, wproc=None, lin=False, q_start=0.0):
    fam_ = "linear" if lin else fam
    """RK4 with ZOH; returns q sampled at the start of each hold and the accel."""
    h = ts / sub
    q, v, z = q_start, 0.0, 0.0
    xe = 0.0  # third-order electrical state
    bl = 0.0  # backlash output
    n = len(u)
    Q = np.zeros(n)
    A = np.zeros(n)
    pre = eff.get("pre") if eff else None
    for i in range(n):
        ui = u[i]
        if fam_ == "input-sq":
            ui = ui + eff["a"] * ui * abs(ui)
        if fam_ == "in-sat":
            ui = eff["L"] * np.tanh(ui / eff["L"])
        if fam_ == "backlash-in":
            d = eff["d"]
            if ui - bl > d:
                bl = ui - d
            elif ui - bl < -d:
                bl = ui + d
            ui = bl
        Q[i] = q

        def f(state, ui):
            q, v, z, xe = state
            F = ui
            if fam_ == "third-order":
                F = xe
            extra = 0.0
            dz = 0.0
            if fam_ == "duffing":
                extra = eff["k3"] * q**3
            if fam_ == "friction":
                extra = eff["fc"] * np.tanh(v / eff["eps"])
            if fam_ == "bouc-wen":
                extra = eff["alpha"] * z
                dz = v - eff["beta"] * abs(v) * z - eff["gamma"] * v * abs(z)
            if fam_ == "preisach-smooth":
                extra = eff["w"] * pre_out[0]
            if fam_ == "process":
                F = F + wproc_i[0]
            a = (F - c * v - k * q - extra) / m
            dxe = (ui - xe) * eff.get("pe", 0.0)
            return np.array([v, a, dz, dxe])

        wproc_i = [wproc[i] if wproc is not None else 0.0]
        s = np.array([q, v, z, xe])
        A[i] = f(s, ui)[1]
        for _ in range(sub):
            if pre is not None:
                pre_out[0] = pre_step(s[0])
            k1 = f(s, ui)
            k2 = f(s + h / 2 * k1, ui)
            k3 = f(s + h / 2 * k2, ui)
            k4 = f(s + h * k3, ui)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        q, v, z, xe = s
    return Q, A


pre_out = [0.0]
# linear response level for scaling the effects
eff0 = {"pe": 0.0}
if fam == "third-order":
    eff0["pe"] = w0 * rng.uniform(0.6, 2.0)
q_lin, _ = simulate(u[:3000], eff=eff0, lin=(fam != "third-order"))
xr = np.std(q_lin)
vr = xr * w0
eff = dict(eff0)
if fam == "duffing":
    eff["k3"] = rng.uniform(0.3, 1.5) * k / xr**2
if fam == "duffing":
    # a hardening spring driven near its resonance can be chaotic: the true
    # model started 1e-3 of the response away then drifts to the output's
    # size, and no model can be judged by its free-run simulation. Such a
    # draw is softened until the start is forgotten (below a quarter of the
    # noise level on the validation part).
    while True:
        qa, _ = simulate(u, eff=eff)
        qb, _ = simulate(u, eff=eff, q_start=1e-3 * xr)
        gap = np.sqrt(np.mean((qa[N_TR:] - qb[N_TR:]) ** 2))
        if gap <= 0.25 * np.std(qa) / 10 ** (snr / 20):
            break
        eff["k3"] *= 0.6
        desc += " softened"
if fam == "friction":
    eff["fc"] = rng.uniform(0.1, 0.4) * k * xr
    eff["eps"] = rng.uniform(0.005, 0.05) * vr
if fam == "bouc-wen":
    eff["alpha"] = rng.uniform(0.3, 1.0) * k
    zr = xr * rng.uniform(0.3, 1.0)
    eff["beta"] = 0.5 / zr
    eff["gamma"] = -0.25 / zr
if fam == "input-sq":
    eff["a"] = rng.uniform(0.2, 0.6) * rng.choice([-1, 1])
if fam == "in-sat":
    eff["L"] = rng.uniform(0.8, 1.5)
if fam == "backlash-in":
    eff["d"] = rng.uniform(0.2, 0.6)
if fam == "preisach-smooth":
    nl = 40
    half = rng.uniform(1.5, 2.5) * xr
    g = (np.arange(nl) + 0.5) / nl * 2 * half - half
    A_, B_ = np.meshgrid(g, g, indexing="ij")
    mask = A_ > B_
    al, be = A_[mask], B_[mask]
    sw = rng.uniform(0.2, 0.6) * half
    dens = np.exp(-((al - be) / sw) ** 2) * np.exp(-(((al + be) / 2) / half) ** 2)
    dens /= dens.sum()
    st = np.where(al + be > 0, -1.0, 1.0)

    def pre_step(x):
        global st
        st = np.where(x >= al, 1.0, np.where(x <= be, -1.0, st))
        return float(np.dot(dens, st))

    eff["pre"] = True
    eff["w"] = rng.uniform(0.3, 0.8) * k * xr
wproc = None
if fam == "process":
    e = rng.standard_normal(N)
    a = np.exp(-2 * np.pi * 0.5 * f0 * ts)
    wproc = np.zeros(N)
    for i in range(1, N):
        wproc[i] = a * wproc[i - 1] + e[i]
    wproc *= rng.uniform(0.1, 0.3) * np.std(u) / np.std(wproc)

Q, Acc = simulate(u, eff=eff, wproc=wproc)
y0 = Acc if fam == "accel" else Q
if fam == "tanh-sensor":
    L = rng.uniform(1.0, 2.0) * np.std(y0)
    y0 = L * np.tanh(y0 / L)
sig = np.std(y0) / 10 ** (snr / 20)
noise = sig * rng.standard_normal(N)
if fam == "ar-noise":
    a = rng.uniform(0.7, 0.95)
    e = noise.copy()
    noise = np.zeros(N)
    for i in range(1, N):
        noise[i] = a * noise[i - 1] + e[i]
    noise *= sig * 2 / np.std(noise)
y = y0 + noise
# floor: the NRMSE of the noise-free output on the validation part
yv, nv = y[N_TR:], noise[N_TR:]
floor = float(np.sqrt(np.mean(nv**2)) / np.std(yv))
if fam == "process":
    floor = None  # process noise: judged by the diagnosis' own floor
for name, sl in [("train.csv", slice(0, N_TR)), ("validate.csv", slice(N_TR, N))]:
    with open(os.path.join(out, name), "w") as fh:
        fh.write("t,u,y\n")
        for i in range(sl.start, sl.stop):
            fh.write(f"{i * ts:.9g},{u[i]:.9g},{y[i]:.9g}\n")
json.dump(
    dict(family=fam, seed=seed, expected=expected, floor=floor, ts=ts, f0=f0, zeta=zeta,
         snr=snr, excitation=str(kind), spp=spp, softened=desc.count("softened"), eff={k: (v if not isinstance(v, bool) else 1) for k, v in eff.items()}),
    open(os.path.join(out, "meta.json"), "w"),
)
print(fam, seed, expected, floor, kind, f"spp {spp:.1f} snr {snr:.1f}")
