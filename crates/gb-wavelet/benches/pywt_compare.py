#!/usr/bin/env python3
"""Time PyWavelets on the transforms of benches/fwt.rs (same sizes, same mode).

Usage: python3 crates/gb-wavelet/benches/pywt_compare.py
Prints the median wall time over repeated runs and the throughput in Msamples/s.
"""
import timeit

import numpy as np
import pywt

N = 1 << 20


def bench(label, fn, repeat=40):
    fn()  # warm up
    times = timeit.repeat(fn, number=1, repeat=repeat)
    t = float(np.median(times))
    print(f"{label:28s} median {t * 1e3:8.3f} ms  min {min(times) * 1e3:8.3f} ms"
          f"  {N / t / 1e6:8.1f} Msamples/s (median)")


def main():
    x = np.random.default_rng(42).random(N) - 0.5
    print(f"PyWavelets {pywt.__version__}, numpy {np.__version__}")
    for name in ["db4", "sym8"]:
        bench(f"dwt/{name}/{N}", lambda: pywt.dwt(x, name, mode="periodization"))
        bench(f"wavedec/{name}/{N}", lambda: pywt.wavedec(x, name, mode="periodization"))
        coeffs = pywt.wavedec(x, name, mode="periodization")
        bench(f"waverec/{name}/{N}", lambda: pywt.waverec(coeffs, name, mode="periodization"))


if __name__ == "__main__":
    main()
