"""Shared fixtures: the `greybox` CLI binary and data it generates.

The CLI is $GREYBOX_BIN, else the workspace's target/{debug,release}/greybox.
Without it the cross-checks skip, unless GREYBOX_REQUIRE_CLI=1 (CI), where
a missing binary fails them."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]


def cli_path() -> Path | None:
    env = os.environ.get("GREYBOX_BIN")
    if env:
        return Path(env)
    for profile in ("debug", "release"):
        p = REPO / "target" / profile / "greybox"
        if p.exists():
            return p
    return None


@pytest.fixture(scope="session")
def cli():
    """Run the CLI with arguments; returns its stdout (fails on error)."""
    path = cli_path()
    if path is None or not path.exists():
        msg = "no greybox CLI binary (cargo build -p greybox-cli, or set GREYBOX_BIN)"
        if os.environ.get("GREYBOX_REQUIRE_CLI") == "1":
            pytest.fail(msg)
        pytest.skip(msg)

    def run(*args: str) -> str:
        r = subprocess.run([str(path), "--quiet", *map(str, args)], capture_output=True, text=True)
        if r.returncode != 0:
            raise AssertionError(f"greybox {' '.join(map(str, args))} failed:\n{r.stdout}\n{r.stderr}")
        return r.stdout

    return run


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """The columns of a CSV written by the CLI, by name."""
    with open(path) as f:
        names = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {n: np.ascontiguousarray(data[:, j]) for j, n in enumerate(names)}


def sample_time(t: np.ndarray) -> float:
    """The CLI's sample time of a uniform time column (its mean step)."""
    return (t[-1] - t[0]) / (len(t) - 1)


@pytest.fixture(scope="session")
def generated(cli, tmp_path_factory):
    """`greybox generate SYSTEM` (3000 + 1500 samples): the folder."""
    made: dict[str, Path] = {}

    def make(system: str) -> Path:
        if system not in made:
            out = tmp_path_factory.mktemp(system)
            cli("generate", system, "-o", out, "--samples", "3000", "--validate-samples", "1500")
            made[system] = out
        return made[system]

    return make
