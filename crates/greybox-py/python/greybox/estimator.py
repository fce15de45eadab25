"""A scikit-learn style estimator for free-run simulation models, with
SysIdentPy's conventions: ``fit(X=inputs, y=output)``, ``predict(X=inputs,
y=initial outputs)``, ``get_params``/``set_params``."""
from __future__ import annotations

from typing import Any, Dict, Optional

import numpy as np

from ._signals import as_vector


class SimulationRegressor:
    """Fit a greybox model (any registry SPEC, ``**options`` as its
    KEY=VALUE options) and predict by free-run simulation.

    ``X``: the inputs, one column per input (a 1-D array is one input);
    ``y``: the output. ``predict(X, y)`` takes the first
    ``model_.history_len`` samples of ``y`` as initial conditions (as
    SysIdentPy does); without ``y`` the model starts as it stores.
    """

    def __init__(self, model: str = "lmn", **options: Any) -> None:
        self.model = model
        self.options: Dict[str, Any] = dict(options)

    def get_params(self, deep: bool = True) -> Dict[str, Any]:
        """The constructor's parameters (``model`` and the options)."""
        return {"model": self.model, **self.options}

    def set_params(self, **params: Any) -> "SimulationRegressor":
        """Set ``model`` or options; returns ``self``."""
        for k, v in params.items():
            if k == "model":
                self.model = v
            else:
                self.options[k] = v
        return self

    def fit(self, X: Any, y: Any) -> "SimulationRegressor":
        """Fit on inputs ``X`` and output ``y``; the model is ``model_``."""
        from . import fit

        self.model_ = fit(X, y, self.model, **self.options)
        self.n_features_in_ = len(self.model_.input_names)
        return self

    def predict(self, X: Any, y: Optional[Any] = None) -> np.ndarray:
        """Free-run simulation of ``X``; ``y`` (optional) gives the initial
        output history."""
        if not hasattr(self, "model_"):
            raise ValueError("this SimulationRegressor is not fitted yet; call fit(X, y) first")
        init = None
        h = self.model_.history_len
        if y is not None and h > 0:
            init = as_vector(y, "y")[:h]
        return self.model_.simulate(X, init=init)

    def score(self, X: Any, y: Any) -> float:
        """R² of the free-run simulation (scikit-learn's regressor score)."""
        yv = as_vector(y, "y")
        e = yv - self.predict(X, yv)
        return float(1.0 - np.sum(e**2) / np.sum((yv - yv.mean()) ** 2))

    def __repr__(self) -> str:
        args = ", ".join([repr(self.model)] + [f"{k}={v!r}" for k, v in self.options.items()])
        return f"SimulationRegressor({args})"
