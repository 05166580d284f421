"""Per-step cost of the fast AaKF.step against the original (reference) step,
side by side in the same process (ratio, min of repeats).

Run: ``.venv/bin/python bench/bench_aakf.py``
"""
import sys
import timeit
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(REPO), str(REPO / "tests")]

from cosim.algorithms.aakf import AakfParams  # noqa: E402
from cosim.algorithms.fast.aakf_fast import AaKF  # noqa: E402
from test_aakf_fast import _ReferenceAaKF  # noqa: E402


def us_per_step(cls, params: AakfParams = AakfParams(sigma_a=300.0)) -> float:
    """Per-step time of ``cls(params)`` (default: one filter, the thesis' aaKF)."""
    f = cls(params)
    m = {"theta_enc": 0.1, "acc_meas": 0.2}
    for _ in range(30000):               # past convergence of the gain sequence
        f.step(m)
    return min(timeit.repeat(lambda: f.step(m), number=20000, repeat=5)) / 20000 * 1e6


if __name__ == "__main__":
    fast, ref = us_per_step(AaKF), us_per_step(_ReferenceAaKF)
    print(f"AaKF.step: {fast:.2f} us/step, reference {ref:.2f} us/step, ratio {ref / fast:.1f}x")
    bank = us_per_step(AaKF, AakfParams())
    print(f"default AaKF (sigma_a bank of {len(AakfParams().sigma_a_bank)}): {bank:.2f} us/step")
