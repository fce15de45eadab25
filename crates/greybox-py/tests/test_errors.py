"""Bad input raises ValueError with the CLI's message; nothing panics."""
from __future__ import annotations

import subprocess

import numpy as np
import pytest

import greybox
from conftest import cli_path


def data(n: int = 600):
    rng = np.random.default_rng(0)
    u = rng.standard_normal(n)
    y = np.convolve(u, [0.0, 0.5, 0.3], mode="full")[:n] + 0.01 * rng.standard_normal(n)
    return u, y


def test_nan_and_infinity():
    u, y = data()
    y[5] = np.nan
    with pytest.raises(ValueError, match="signals contain NaN or infinity"):
        greybox.fit(u, y, "linear")
    u2, y2 = data()
    u2[3] = np.inf
    with pytest.raises(ValueError, match="signals contain NaN or infinity"):
        greybox.diagnose(u2, y2)
    with pytest.raises(ValueError, match="signals contain NaN or infinity"):
        greybox.fit(u2[:-1].tolist() + [None], y2, "linear")


def test_length_mismatch():
    u, y = data()
    with pytest.raises(ValueError, match="input 'u' has 599 samples, output has 600"):
        greybox.fit(u[:-1], y, "linear")
    with pytest.raises(ValueError, match="input 'u' has 599 samples, output has 600"):
        greybox.diagnose(u[:-1], y)


def cli_error(cli_bin, *args) -> str:
    r = subprocess.run([str(cli_bin), "--quiet", *map(str, args)], capture_output=True, text=True)
    assert r.returncode != 0
    return r.stderr.strip().splitlines()[-1].removeprefix("greybox: error: ")


def test_too_short_with_the_clis_message(cli, tmp_path):
    u, y = data(30)
    csv = tmp_path / "short.csv"
    np.savetxt(csv, np.c_[u, y], delimiter=",", header="u,y", comments="")
    with pytest.raises(ValueError) as e:
        greybox.diagnose(u, y)
    assert str(e.value) == cli_error(cli_path(), "diagnose", csv) == "fit block: 15 samples, at least 60 are needed"
    csv3 = tmp_path / "three.csv"
    np.savetxt(csv3, np.c_[u[:3], y[:3]], delimiter=",", header="u,y", comments="")
    with pytest.raises(ValueError) as e:
        greybox.fit(u[:3], y[:3], "linear")
    # the CLI names the file first
    assert cli_error(cli_path(), "fit", csv3, "--model", "linear", "-o", tmp_path / "m.gbm") == f"{csv3}: {e.value}"


def test_dataframe_like_columns_name_the_inputs():
    class Frame:
        """What greybox uses of a pandas DataFrame: columns and __array__."""

        def __init__(self, a):
            self.a, self.columns = a, ["valve", "pump"]

        def __array__(self, dtype=None, copy=None):
            return self.a.astype(dtype or np.float64)

    u, y = data()
    m = greybox.fit(Frame(np.c_[u, -u]), y, "linear")
    assert m.input_names == ["valve", "pump"]


def test_bad_options():
    u, y = data()
    with pytest.raises(ValueError, match="order must be 1..=.* or auto, got '0'"):
        greybox.diagnose(u, y, order=0)
    with pytest.raises(ValueError, match="max_steps must be 1..=4, got 9"):
        greybox.diagnose(u, y, max_steps=9)
    with pytest.raises(ValueError, match="expected a 1-D or 2-D array"):
        greybox.fit(np.zeros((3, 3, 3)), y)
    with pytest.raises(ValueError, match="not a numeric array"):
        greybox.fit(["a"] * 600, y)
    with pytest.raises(ValueError, match="give both u_val and y_val"):
        greybox.diagnose(u, y, u_val=u)
    with pytest.raises(OSError):
        greybox.load("/nonexistent/model.gbm")
    m = greybox.fit(u, y, "linear")
    with pytest.raises(ValueError, match="init must be"):
        m.simulate(u, init="nope")
    with pytest.raises(ValueError, match="exceeds"):
        m.simulate(u[:10], init=y[:20])
    with pytest.raises(ValueError, match="the model has 1 inputs, 2 signals were given"):
        m.simulate(np.c_[u, u])


def test_lists_and_pandas_like_columns():
    u, y = data()
    a = greybox.fit(u, y, "linear").simulate(u)
    b = greybox.fit(u.tolist(), list(y), "linear").simulate(u.tolist())
    np.testing.assert_array_equal(a, b)
    c = greybox.fit(u[:, None], y[:, None], "linear").simulate(u[:, None])
    np.testing.assert_array_equal(a, c)
