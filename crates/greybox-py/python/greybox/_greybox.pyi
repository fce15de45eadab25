"""Type stubs of the compiled core (use the public API in ``greybox``)."""
from typing import List, Optional, Tuple

import numpy as np
import numpy.typing as npt

__version__: str

F64 = npt.NDArray[np.float64]

class _Model:
    class_name: str
    input_names: List[str]
    output_names: List[str]
    sample_time: Optional[float]
    n_parameters: int
    n_states: int
    history_len: int
    notes: List[str]
    def simulate(self, inputs: List[F64], init_kind: str = "stored", init_values: Optional[F64] = None) -> F64: ...
    def stepper(self, state: Optional[F64] = None) -> _Stepper: ...
    def save(self, path: str) -> None: ...
    def describe(self) -> str: ...

class _Stepper:
    def step(self, u: List[float]) -> List[float]: ...

class _Diagnosis:
    causes: List[str]
    final_model: _Model
    def to_json(self) -> str: ...
    def to_text(self) -> str: ...
    def split_text(self) -> str: ...
    def report_html(self, path: str, title: str) -> None: ...

def fit(
    inputs: List[F64], output: F64, input_names: List[str], output_name: str, sample_time: Optional[float], spec: str
) -> _Model: ...
def fit_model_file(
    path: str,
    inputs: List[F64],
    output: F64,
    input_names: Optional[List[str]],
    output_name: Optional[str],
    sample_time: Optional[float],
) -> _Model: ...
def load(path: str) -> _Model: ...
def recipes_help() -> str: ...
def diagnose_records(
    train: Tuple[List[F64], F64],
    validate: Optional[Tuple[List[F64], F64]],
    input_names: List[str],
    output_name: str,
    sample_time: Optional[float],
    order: str,
    max_steps: int,
    more: List[Tuple[List[F64], F64]] = ...,
) -> _Diagnosis: ...
def wavedec(x: F64, wavelet: str, level: Optional[int], mode: str) -> List[F64]: ...
def waverec(coeffs: List[F64], wavelet: str, mode: str) -> F64: ...
def denoise(x: F64, wavelet: str, threshold: str, mode: str) -> Tuple[F64, float]: ...
