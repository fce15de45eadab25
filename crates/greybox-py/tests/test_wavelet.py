"""Wavelets on numpy arrays: round trips and known values."""
from __future__ import annotations

import numpy as np
import pytest

from greybox import wavelet


@pytest.mark.parametrize("name", ["haar", "db4", "db8", "sym4", "coif2"])
@pytest.mark.parametrize("mode", ["symmetric", "periodization", "zero", "periodic"])
def test_round_trip(name, mode):
    x = np.random.default_rng(0).standard_normal(1000)
    c = wavelet.wavedec(x, name, 3, mode)
    assert len(c) == 4
    back = wavelet.waverec(c, name, mode)
    assert np.max(np.abs(back[: len(x)] - x)) < 1e-10


def test_known_haar_values():
    c = wavelet.wavedec(np.arange(8.0), "haar", 2, "periodization")
    r2 = np.sqrt(2.0)
    np.testing.assert_allclose(c[0], [3.0, 11.0], atol=1e-14)  # (0+1+2+3)/2, (4+5+6+7)/2
    np.testing.assert_allclose(c[1], [-2.0, -2.0], atol=1e-14)
    np.testing.assert_allclose(c[2], [-1 / r2] * 4, atol=1e-14)


def test_known_db2_values():
    # db2 has two vanishing moments: a constant's details are 0 and its
    # approximation is c·sqrt(2) (sum of the low-pass filter) under symmetric
    # extension; a ramp's interior details are 0
    a, d = wavelet.wavedec(np.full(8, 3.0), "db2", 1, "symmetric")
    assert len(a) == len(d) == 5  # pywt: floor((8 + 4 - 1) / 2)
    np.testing.assert_allclose(a, 3.0 * np.sqrt(2.0), rtol=1e-13)
    np.testing.assert_allclose(d, 0.0, atol=1e-13)
    _, d = wavelet.wavedec(np.arange(8.0), "db2", 1, "symmetric")
    np.testing.assert_allclose(d[1:4], 0.0, atol=1e-12)


def test_denoise_reduces_error_and_checks_input():
    rng = np.random.default_rng(1)
    t = np.linspace(0, 1, 1024)
    clean = np.sin(8 * np.pi * t)
    noisy = clean + 0.2 * rng.standard_normal(len(t))
    out = wavelet.denoise(noisy)
    assert out.shape == noisy.shape
    assert np.mean((out - clean) ** 2) < 0.3 * np.mean((noisy - clean) ** 2)
    _, sigma = wavelet.denoise_with_sigma(noisy, "db8", "universal")
    assert sigma == pytest.approx(0.2, rel=0.15)
    with pytest.raises(ValueError, match="wavelet"):
        wavelet.wavedec(noisy, "nope", 2, "symmetric")
    with pytest.raises(ValueError, match="mode"):
        wavelet.wavedec(noisy, "db4", 2, "nope")
    with pytest.raises(ValueError, match="threshold"):
        wavelet.denoise(noisy, threshold="nope")
    with pytest.raises(ValueError):
        wavelet.denoise(np.r_[noisy, np.nan])
