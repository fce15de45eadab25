"""Fast wavelet transforms and denoising on numpy arrays, with the names
and conventions of PyWavelets (``wavedec``/``waverec`` bands
``[a_J, d_J, …, d_1]``, modes ``symmetric``, ``periodization``, …)."""
from __future__ import annotations

from typing import Any, List, Optional, Sequence

import numpy as np

from . import _greybox
from ._signals import as_vector

__all__ = ["wavedec", "waverec", "denoise", "denoise_with_sigma"]


def wavedec(x: Any, wavelet: str = "db4", level: Optional[int] = None, mode: str = "symmetric") -> List[np.ndarray]:
    """Multilevel decomposition ``[a_J, d_J, …, d_1]`` like
    ``pywt.wavedec(x, wavelet, mode, level)``; ``level=None`` is the
    wavelet's maximum level for ``len(x)``."""
    return _greybox.wavedec(as_vector(x, "x"), wavelet, None if level is None else int(level), mode)


def waverec(coeffs: Sequence[Any], wavelet: str = "db4", mode: str = "symmetric") -> np.ndarray:
    """The signal of ``[a_J, d_J, …, d_1]`` like ``pywt.waverec``."""
    return _greybox.waverec([as_vector(c, "coefficients") for c in coeffs], wavelet, mode)


def denoise(x: Any, wavelet: str = "db8", threshold: str = "sure", mode: str = "symmetric") -> np.ndarray:
    """Wavelet denoising (``greybox denoise``): soft thresholds on every
    detail level by ``threshold`` (``sure``, ``universal``, ``bayes``,
    ``ebayes``), noise level estimated from the finest level."""
    return denoise_with_sigma(x, wavelet, threshold, mode)[0]


def denoise_with_sigma(
    x: Any, wavelet: str = "db8", threshold: str = "sure", mode: str = "symmetric"
) -> "tuple[np.ndarray, float]":
    """:func:`denoise` and the noise level it used."""
    return _greybox.denoise(as_vector(x, "x"), wavelet, threshold, mode)
