"""greybox: grey-box identification of nonlinear dynamical systems.

Diagnose a model's misfit on numpy arrays (nonlinearity, hysteresis,
dynamics, noise), fit any model of the registry, simulate, step online,
and save models in the CLI's ``.gbm`` format::

    import numpy as np, greybox
    d = greybox.diagnose(u, y, u_val, y_val)
    print(d.causes, d.final_model)
    y_sim = d.final_model.simulate(u_val)

Results are bit-identical to the ``greybox`` command line: both make the
same library calls.
"""
from __future__ import annotations

import json
import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _greybox, wavelet
from ._signals import as_columns, as_vector, column_names, input_names_for, signals
from .estimator import SimulationRegressor

__version__: str = _greybox.__version__

__all__ = [
    "Diagnosis",
    "Model",
    "SimulationRegressor",
    "diagnose",
    "fit",
    "load",
    "models_help",
    "spec_string",
    "wavelet",
]

PathLike = Union[str, "os.PathLike[str]"]
Init = Union[None, str, Sequence[float], np.ndarray]


class Model:
    """A fitted model of any class (what ``greybox fit`` saves).

    ``simulate`` runs it free on input columns; ``step``/``reset`` run it one
    sample at a time (bit-identical to ``simulate(u, init="rest")``);
    ``save``/``greybox.load`` use the CLI's model file format.
    """

    def __init__(self, core: "_greybox._Model") -> None:
        self._core = core
        self._stepper: Optional["_greybox._Stepper"] = None

    @property
    def class_name(self) -> str:
        """The registry's class tag (``io-network``, ``physics``, …)."""
        return self._core.class_name

    @property
    def input_names(self) -> List[str]:
        """Names of the inputs, in column order."""
        return self._core.input_names

    @property
    def output_name(self) -> str:
        """Name of the (first) output."""
        names = self._core.output_names
        return names[0] if names else ""

    @property
    def sample_time(self) -> Optional[float]:
        """Sample time in seconds, when known."""
        return self._core.sample_time

    @property
    def n_parameters(self) -> int:
        """Number of estimated parameters."""
        return self._core.n_parameters

    @property
    def history_len(self) -> int:
        """Leading measured outputs an input-output model takes as history
        (0 for state-space models)."""
        return self._core.history_len

    @property
    def notes(self) -> List[str]:
        """Facts about the fit (chosen structure, scores), one per line."""
        return self._core.notes

    def describe(self) -> str:
        """One line: the dynamics and the noise model."""
        return self._core.describe()

    def __repr__(self) -> str:
        return f"<greybox.Model {self.class_name}: {self.describe()}; {', '.join(self.input_names)} -> {self.output_name}>"

    def simulate(self, u: Any, init: Init = None) -> np.ndarray:
        """Free-run simulation of the inputs ``u`` (1-D: one input; 2-D: one
        input per column, in ``input_names`` order).

        ``init``: ``None`` or ``"stored"`` starts as the model stores (as
        ``greybox simulate`` without ``--init-window``); ``"rest"`` from
        rest; an array of the first measured outputs is an init window (as
        ``--init-window len(init)``). Returns the simulated output (a 2-D
        array, one column per output, for several outputs).
        """
        cols = as_columns(u, "u")
        kind, values = _init(init)
        y = self._core.simulate(cols, kind, values)
        n_out = len(self._core.output_names)
        return y if n_out <= 1 else y.reshape(n_out, -1).T.copy()

    def reset(self, state: Any = None) -> None:
        """Restart online use from rest, or from ``state`` (the output
        history of an input-output model, the state of a state-space
        model)."""
        s = None if state is None else as_vector(state, "state")
        self._stepper = self._core.stepper(s)

    def step(self, u_t: Any) -> Union[float, List[float]]:
        """Advance one sample with the inputs ``u_t`` (a number, or one value
        per input); returns the output (a list for several outputs). Starts
        from rest unless ``reset`` was called."""
        if self._stepper is None:
            self.reset()
        assert self._stepper is not None
        u = np.atleast_1d(np.asarray(u_t, dtype=np.float64)).tolist()
        y = self._stepper.step(u)
        return y[0] if len(y) == 1 else y

    def save(self, path: PathLike) -> None:
        """Write the model file (the CLI's ``.gbm`` format) atomically."""
        self._core.save(os.fspath(path))


def _init(init: Init) -> "tuple[str, Optional[np.ndarray]]":
    if init is None:
        return "stored", None
    if isinstance(init, str):
        if init not in ("stored", "rest"):
            raise ValueError(f"init must be None, 'stored', 'rest' or an array of measured outputs, got '{init}'")
        return init, None
    return "window", as_vector(init, "init")


class Diagnosis:
    """The result of :func:`diagnose`: the accepted causes, every candidate
    step, the verdict of the residual tests and the final model."""

    def __init__(self, core: "_greybox._Diagnosis") -> None:
        self._core = core
        self._report: Dict[str, Any] = json.loads(core.to_json())

    @property
    def causes(self) -> List[str]:
        """Accepted causes in order (``[]``: no extension paid)."""
        return list(self._core.causes)

    @property
    def steps(self) -> List[Dict[str, Any]]:
        """Every candidate extension per iteration (cause, evidence,
        NRMSE before/after, gain and its interval, accepted)."""
        return self._report["steps"]

    @property
    def verdict(self) -> str:
        """What the residual tests say about the final model."""
        return self._report["verdict"]["text"]

    @property
    def report(self) -> Dict[str, Any]:
        """The whole report (the JSON of ``greybox diagnose --json``)."""
        return self._report

    @property
    def baseline_nrmse(self) -> float:
        """Report-block NRMSE of the engineer's model."""
        return self._report["baseline"]["nrmse"]

    @property
    def final_nrmse(self) -> float:
        """Report-block NRMSE of the final model."""
        return self._report["final"]["nrmse"]

    @property
    def final_model(self) -> Model:
        """The final (possibly extended) model, as ``greybox diagnose
        --save`` writes it (refitted on all training data when that was
        done and kept)."""
        return Model(self._core.final_model)

    def to_json(self) -> str:
        """The report as ``greybox diagnose --json`` writes it."""
        return self._core.to_json()

    def to_text(self) -> str:
        """The report as ``greybox diagnose`` prints it."""
        return self._core.to_text()

    def report_html(self, path: PathLike, title: str = "greybox diagnosis") -> None:
        """Write the HTML report (``greybox diagnose --report``)."""
        self._core.report_html(os.fspath(path), title)

    def __repr__(self) -> str:
        causes = ", ".join(self.causes) or "none"
        return (
            f"<greybox.Diagnosis causes: {causes}; NRMSE {self.baseline_nrmse:.4f} -> "
            f"{self.final_nrmse:.4f}; final: {self._report['final']['spec']}>"
        )


def diagnose(
    u: Any,
    y: Any,
    u_val: Any = None,
    y_val: Any = None,
    order: Union[int, str] = 2,
    max_steps: int = 4,
    input_names: Optional[Sequence[str]] = None,
    output_name: str = "y",
    sample_time: Optional[float] = None,
    experiments: Optional[Sequence[Tuple[Any, Any]]] = None,
) -> Diagnosis:
    """Simulate the engineer's linear model of ``order`` (or ``"auto"``),
    name the cause of its misfit, extend it and measure the gain on
    held-out data: ``greybox diagnose train.csv --validate val.csv``.

    ``u``: inputs (1-D, or one column per input), ``y``: output. With
    ``u_val``/``y_val`` the training data is split 75/25 into fit and
    select blocks and the validation record is the report data; without,
    one record is split into fit/select/report blocks (50/25/25 %).

    ``experiments``: further training records ``[(u2, y2), ...]``, each a
    separate experiment (no regressor and no simulated state spans two
    records): ``greybox diagnose --train a.csv --train b.csv``. Every
    training record is split 75/25 into fit and select parts; without a
    validation record the last one is the report data, held out whole, and
    :attr:`Diagnosis.final_model` is then refitted on every record.
    """
    cols, out = signals(u, y)
    names = input_names_for(u, len(cols), input_names)
    more = [signals(ue, ye) for ue, ye in (experiments or [])]
    for i, (c, _) in enumerate(more):
        if len(c) != len(cols):
            raise ValueError(f"experiment {i + 2} has {len(c)} inputs, the first record {len(cols)}")
    val = None
    if (u_val is None) != (y_val is None):
        raise ValueError("give both u_val and y_val, or neither")
    if u_val is not None:
        val = signals(u_val, y_val)
        if len(val[0]) != len(cols):
            raise ValueError(f"the validation data has {len(val[0])} inputs, the training data {len(cols)}")
    core = _greybox.diagnose_records(
        (cols, out), val, names, output_name, sample_time, str(order), int(max_steps), more
    )
    return Diagnosis(core)


def spec_string(model: str, options: Dict[str, Any]) -> str:
    """The CLI's model SPEC of ``model`` with ``options`` as KEY=VALUE
    (lists as ``a/b``, booleans as ``true``/``false``)."""

    def text(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (list, tuple, np.ndarray)):
            return "/".join(text(x) for x in v)
        return str(v)

    opts = ",".join(f"{k}={text(v)}" for k, v in options.items() if v is not None)
    if not opts:
        return model
    return f"{model}{',' if ':' in model else ':'}{opts}"


def fit(
    u: Any,
    y: Any,
    model: str = "lmn",
    *,
    model_file: Optional[PathLike] = None,
    input_names: Optional[Sequence[str]] = None,
    output_name: Optional[str] = None,
    sample_time: Optional[float] = None,
    **options: Any,
) -> Model:
    """Fit any model of the registry: ``greybox fit --model SPEC``.

    ``model`` is a SPEC (``"lmn"``, ``"linear"``, ``"lmn+preisach"``,
    ``"state-space+hysteresis"``, …); ``options`` become its KEY=VALUE
    options, e.g. ``fit(u, y, "lmn", order=3, max_leaves=10)`` is
    ``--model lmn:order=3,max_leaves=10``. With ``model_file`` (a TOML
    physics model file) the engineer's continuous-time model is fitted
    instead; the signal names then default to the file's.
    """
    cols, out = signals(u, y)
    if model_file is not None:
        if options:
            raise ValueError(f"options {sorted(options)} do not apply to a model file")
        names = None if input_names is None and column_names(u) is None else input_names_for(u, len(cols), input_names)
        core = _greybox.fit_model_file(os.fspath(model_file), cols, out, names, output_name, sample_time)
        return Model(core)
    names = input_names_for(u, len(cols), input_names)
    spec = spec_string(model, options)
    core = _greybox.fit(cols, out, names, output_name or "y", sample_time, spec)
    return Model(core)


def load(path: PathLike) -> Model:
    """Read a model file of any class (``.gbm``, as the CLI writes)."""
    return Model(_greybox.load(os.fspath(path)))


def models_help() -> str:
    """Every model of the registry with its options (``greybox fit --help``)."""
    return _greybox.recipes_help()
