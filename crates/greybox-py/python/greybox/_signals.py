"""Turning what users pass (numpy arrays, lists, pandas columns) into the
contiguous float64 columns the compiled core takes."""
from __future__ import annotations

from typing import Any, List, Optional, Sequence, Tuple

import numpy as np


def column_names(x: Any) -> Optional[List[str]]:
    """The column names of a pandas DataFrame (or the name of a Series)."""
    cols = getattr(x, "columns", None)
    if cols is not None:
        return [str(c) for c in cols]
    name = getattr(x, "name", None)
    if isinstance(name, str) and hasattr(x, "to_numpy"):
        return [name]
    return None


def as_vector(x: Any, what: str) -> np.ndarray:
    """A 1-D contiguous float64 array (ValueError otherwise)."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: not a numeric array ({e})") from None
    if a.ndim == 2 and 1 in a.shape:
        a = a.reshape(-1)
    if a.ndim != 1:
        raise ValueError(f"{what}: expected a 1-D array, got shape {a.shape}")
    return np.ascontiguousarray(a)


def as_columns(u: Any, what: str = "u") -> List[np.ndarray]:
    """The input signals: a 1-D array is one input, a 2-D array holds one
    input per column (samples as rows)."""
    try:
        a = np.asarray(u, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: not a numeric array ({e})") from None
    if a.ndim == 1:
        return [np.ascontiguousarray(a)]
    if a.ndim == 2:
        return [np.ascontiguousarray(a[:, j]) for j in range(a.shape[1])]
    raise ValueError(f"{what}: expected a 1-D or 2-D array (samples as rows), got shape {a.shape}")


def input_names_for(u: Any, n: int, given: Optional[Sequence[str]]) -> List[str]:
    """`given`, else a DataFrame's column names, else `u` (one input) or
    `u1, u2, …`."""
    if given is not None:
        names = [given] if isinstance(given, str) else [str(s) for s in given]
        if len(names) != n:
            raise ValueError(f"{len(names)} input names for {n} input signals")
        return names
    found = column_names(u)
    if found is not None and len(found) == n:
        return found
    return ["u"] if n == 1 else [f"u{j + 1}" for j in range(n)]


def signals(u: Any, y: Any) -> Tuple[List[np.ndarray], np.ndarray]:
    """Input columns and output vector of one record."""
    return as_columns(u, "u"), as_vector(y, "y")
