"""Models: save/load across Python and the CLI, stepping, physics model
files, the scikit-learn style estimator."""
from __future__ import annotations

import numpy as np
import pytest

import greybox
from conftest import read_csv, sample_time


def narx_data(n: int = 2000, seed: int = 3):
    """A mildly nonlinear second-order system with two inputs."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, 2))
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = 1.1 * y[k - 1] - 0.4 * y[k - 2] + 0.5 * np.tanh(u[k - 1, 0]) + 0.2 * u[k - 1, 1]
    return u, y + 0.01 * rng.standard_normal(n)


def test_python_model_runs_in_the_cli_and_back(cli, generated, tmp_path):
    d = generated("saturation")
    tr, va = read_csv(d / "train.csv"), read_csv(d / "validate.csv")
    m = greybox.fit(tr["u"], tr["y"], "lmn", max_leaves=4)
    m.save(tmp_path / "py.gbm")
    cli("simulate", tmp_path / "py.gbm", d / "validate.csv", "-o", tmp_path / "sim.csv")
    np.testing.assert_array_equal(read_csv(tmp_path / "sim.csv")["y_sim"], m.simulate(va["u"]))
    back = greybox.load(tmp_path / "py.gbm")
    assert back.describe() == m.describe() and repr(back) == repr(m)
    np.testing.assert_array_equal(back.simulate(va["u"]), m.simulate(va["u"]))


def test_cli_model_loads_in_python(cli, generated, tmp_path):
    d = generated("linear")
    cli("fit", d / "train.csv", "--model", "linear", "-o", tmp_path / "cli.gbm")
    cli("simulate", tmp_path / "cli.gbm", d / "validate.csv", "-o", tmp_path / "sim.csv", "--init-window", "50")
    m = greybox.load(tmp_path / "cli.gbm")
    va = read_csv(d / "validate.csv")
    assert m.input_names == ["u"] and m.output_name == "y"
    assert m.sample_time == pytest.approx(sample_time(va["t"]))
    sim = m.simulate(va["u"], init=va["y"][:50])
    np.testing.assert_array_equal(read_csv(tmp_path / "sim.csv")["y_sim"], sim)


@pytest.mark.parametrize("spec,options", [("linear", {}), ("lmn", {"max_leaves": 5}), ("lmn", {"weights": "tree"})])
def test_step_is_bit_identical_to_simulate(spec, options):
    u, y = narx_data()
    m = greybox.fit(u, y, spec, **options)
    sim = m.simulate(u, init="rest")
    m.reset()
    stepped = np.array([m.step(u_t) for u_t in u])
    np.testing.assert_array_equal(stepped, sim)
    # from a measured output history
    h = m.history_len
    assert h > 0
    m.reset(y[:h])
    again = np.array([m.step(u_t) for u_t in u[:100]])
    assert np.isfinite(again).all()
    with pytest.raises(ValueError, match="the model has 2 inputs, 1 values were given"):
        m.step(1.0)


def test_model_describes_itself_and_fits_with_options():
    u, y = narx_data()
    m = greybox.fit(u, y, "lmn", order=2, max_leaves=3, input_names=["a", "b"])
    assert m.input_names == ["a", "b"] and m.class_name
    assert "3 affine local models" in m.describe() and m.n_parameters > 0
    assert repr(m).startswith("<greybox.Model ") and "a, b -> y" in repr(m)
    sim = m.simulate(u, init=y[: m.history_len])
    nrmse = np.sqrt(np.mean((y - sim) ** 2)) / np.std(y)
    assert nrmse < 0.2, nrmse
    with pytest.raises(ValueError, match="model spec 'lmn:max_leaves=0'"):
        greybox.fit(u, y, "lmn", max_leaves=0)
    with pytest.raises(ValueError, match="unknown model spec 'nope'"):
        greybox.fit(u, y, "nope")


FIRST_ORDER = """
name = "first-order"
inputs = ["u"]
sample_time = 0.1

[states]
x = { initial = 0.0 }

[parameters]
a = { value = 1.0, min = 0.0, max = 10.0 }
b = { value = 1.0, min = 0.0, max = 10.0 }

[equations]
x = ["-a*x", "b*u"]

[outputs]
y = "x"
"""


def test_physics_model_file(tmp_path):
    path = tmp_path / "first_order.toml"
    path.write_text(FIRST_ORDER)
    rng = np.random.default_rng(7)
    u = np.repeat(rng.standard_normal(100), 20)
    # exact discretisation of dx/dt = -2 x + 3 u under zero-order hold
    phi = np.exp(-2.0 * 0.1)
    y = np.zeros(len(u))
    for k in range(1, len(u)):
        y[k] = phi * y[k - 1] + (1 - phi) * 1.5 * u[k - 1]
    m = greybox.fit(u, y + 1e-3 * rng.standard_normal(len(u)), model_file=path)
    assert m.class_name == "physics"
    # the fit report's parameter table: the truth a = 2, b = 3 within 1 %
    est = {n.split()[0]: float(n.split()[1]) for n in m.notes if n.split()[:1] in (["a"], ["b"])}
    assert est == pytest.approx({"a": 2.0, "b": 3.0}, rel=0.01), m.notes
    sim = m.simulate(u, init="rest")
    assert np.sqrt(np.mean((sim - y) ** 2)) < 5e-3
    m.save(tmp_path / "phys.gbm")
    np.testing.assert_array_equal(greybox.load(tmp_path / "phys.gbm").simulate(u, init="rest"), sim)
    with pytest.raises(ValueError, match="not the model's inputs"):
        greybox.fit(u, y, model_file=path, input_names=["v"])


def test_simulation_regressor():
    u, y = narx_data()
    est = greybox.SimulationRegressor("lmn", max_leaves=3)
    assert est.get_params() == {"model": "lmn", "max_leaves": 3}
    assert est.set_params(max_leaves=4) is est and est.get_params()["max_leaves"] == 4
    with pytest.raises(ValueError, match="not fitted"):
        est.predict(u)
    est.fit(u[:1500], y[:1500])
    assert est.n_features_in_ == 2
    pred = est.predict(u[1500:], y[1500:])
    assert pred.shape == (500,)
    assert est.score(u[1500:], y[1500:]) > 0.9
    np.testing.assert_array_equal(pred, est.model_.simulate(u[1500:], init=y[1500 : 1500 + est.model_.history_len]))


def test_fits_release_the_gil():
    """Another Python thread keeps running while a fit is busy in Rust: the
    main thread spins through most of the fit's duration."""
    import threading
    import time

    u, y = narx_data(4000)
    started, done = threading.Event(), threading.Event()
    span = []

    def work():
        started.set()
        t0 = time.perf_counter()
        greybox.fit(u, y, "lmn", max_leaves=8)
        span.append(time.perf_counter() - t0)
        done.set()

    t = threading.Thread(target=work)
    t.start()
    first = last = None
    while not done.is_set():
        if started.is_set():
            now = time.perf_counter()
            first = now if first is None else first
            last = now
    t.join()
    assert first is not None and last is not None
    # with the GIL held the main thread would stop when the fit enters Rust
    assert last - first > 0.5 * span[0], (last - first, span[0])
