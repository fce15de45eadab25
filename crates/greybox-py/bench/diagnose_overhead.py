"""Time `greybox.diagnose` from Python against `greybox diagnose` (the CLI)
on the same generated data, and check they give the same report.

    python crates/greybox-py/bench/diagnose_overhead.py --cli target/release/greybox [--runs 5] [SYSTEM ...]

For each system: `greybox generate SYSTEM` (8000 + 4000 samples, seed 1),
then alternately (i) the CLI's wall time for `greybox diagnose train.csv
--validate validate.csv --json d.json`, (ii) a fresh Python process that
imports greybox, reads both CSVs with numpy and diagnoses (wall time), and
(iii) the `greybox.diagnose` call alone in this process. Prints medians.
"""
import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import greybox

SCRIPT = """
import sys, numpy as np, greybox
d = sys.argv[1]
tr = np.loadtxt(d + "/train.csv", delimiter=",", skiprows=1)
va = np.loadtxt(d + "/validate.csv", delimiter=",", skiprows=1)
ts = (tr[-1, 0] - tr[0, 0]) / (len(tr) - 1)
r = greybox.diagnose(tr[:, 1], tr[:, 2], va[:, 1], va[:, 2], sample_time=ts)
open(d + "/py.json", "w").write(r.to_json())
"""


def wall(cmd):
    t = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cli", default="target/release/greybox")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("systems", nargs="*", default=["linear", "saturation", "shock-absorber"])
    a = ap.parse_args()
    print(f"greybox {greybox.__version__}, numpy {np.__version__}, Python {sys.version.split()[0]}")
    print("| system | CLI wall | Python process wall | overhead | `greybox.diagnose` call | same report |")
    print("|---|---|---|---|---|---|")
    for system in a.systems:
        d = Path(tempfile.mkdtemp()) / system
        subprocess.run([a.cli, "generate", system, "-o", d, "--quiet"], check=True, capture_output=True)
        tr = np.loadtxt(d / "train.csv", delimiter=",", skiprows=1)
        va = np.loadtxt(d / "validate.csv", delimiter=",", skiprows=1)
        ts = (tr[-1, 0] - tr[0, 0]) / (len(tr) - 1)
        cli, proc, call = [], [], []
        for _ in range(a.runs):
            cli.append(wall([a.cli, "diagnose", d / "train.csv", "--validate", d / "validate.csv", "--json", d / "cli.json", "--quiet"]))
            proc.append(wall([sys.executable, "-c", SCRIPT, str(d)]))
            t = time.perf_counter()
            greybox.diagnose(tr[:, 1], tr[:, 2], va[:, 1], va[:, 2], sample_time=ts)
            call.append(time.perf_counter() - t)
        same = json.loads((d / "cli.json").read_text()) == json.loads((d / "py.json").read_text())
        c, p, k = (float(np.median(x)) for x in (cli, proc, call))
        print(f"| {system} | {c:.3f} s | {p:.3f} s | {100 * (p / c - 1):+.1f} % | {k:.3f} s ({100 * (k / c - 1):+.1f} %) | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
