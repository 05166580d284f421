"""``cosim estimate`` / ``cosim identify``: the algorithms over one trial log
(:mod:`cosim.offline.estimation`).

    cosim estimate --log LOG --out OUT.csv [--sigma-a S] [--sigma-b S] [--burn-in S]
    cosim identify --log LOG --out OUT.json [--speed aakf|encoder] [--sigma-a S] [--sigma-b S]
"""
from __future__ import annotations

import argparse
import sys
from typing import Any

from .exitcodes import BAD_INPUT, CANNOT_TELL, OK


def _print_err(exc: BaseException) -> None:
    print(f"cosim: error: {exc}", file=sys.stderr)


def _aakf_params_arg(a: argparse.Namespace):
    """The aaKF parameters ``--sigma-a`` / ``--sigma-b`` give (None: the defaults)."""
    from ..algorithms.aakf import AakfParams
    kw: dict[str, Any] = {}
    if a.sigma_a is not None:
        kw["sigma_a"] = a.sigma_a                    # one filter with this sigma_a
    if a.sigma_b is not None:
        kw["sigma_b"] = a.sigma_b
    return AakfParams(**kw) if kw else None


def _cmd_estimate(a: argparse.Namespace) -> int:
    from ..logs.trial_log import TrialLogError
    from ..offline.estimation import estimate
    try:
        s = estimate(a.log, a.out, _aakf_params_arg(a), burn_in_s=a.burn_in)
    except (TrialLogError, OSError, ValueError, FloatingPointError) as exc:
        _print_err(exc)
        return BAD_INPUT
    if s["verdict"] == "cannot_judge":
        print(f"{s['samples']} samples -> {s['out']}; cannot judge the estimate: "
              f"{s['cannot_judge']}")
        return CANNOT_TELL
    w = s["whiteness"]
    verdict = {k: w[k].get("white") for k in ("innov_enc_rad", "innov_acc_m_s2")}
    print(f"{s['samples']} samples -> {s['out']}; final bias {s['final_bias_m_s2']:.4g} m/s^2; "
          f"innovations white (enc, acc): {verdict['innov_enc_rad']}, {verdict['innov_acc_m_s2']}; "
          f"reset fired {100 * (s['reset_fraction'] or 0):.1f} % of samples")
    return OK


def _cmd_identify(a: argparse.Namespace) -> int:
    from ..logs.trial_log import TrialLogError
    from ..offline.estimation import identify
    try:
        r = identify(a.log, a.out, speed=a.speed, aakf_params=_aakf_params_arg(a))
    except (TrialLogError, OSError, ValueError, FloatingPointError) as exc:
        _print_err(exc)
        return BAD_INPUT
    f, st = r["final"], r["settling_time_s"]
    par = r["identification"]["parameters"]

    def fmt(v: Any) -> str:
        return "nan" if v is None else f"{v:.4g}"

    def rse(k: str) -> str:
        v = par[k]["relative_se"]
        return "inf" if v is None else f"{100 * v:.2g} %"

    head = (f"{r['samples']} samples ({r['updates']} used), speed {r['speed']}, Kt {r['Kt']:.4g} "
            f"N m/A ({r['Kt_source']}) -> {r['out']}")
    if r["verdict"] == "cannot_identify":
        print(head + "\ncannot identify: the log does not determine the parameters:\n  "
              + "\n  ".join(r["identification"]["reasons"]))
        return CANNOT_TELL
    print(head + f"\n  J {fmt(f['J'])} kg m^2 (+-{rse('J')}), b {fmt(f['b'])} N m s/rad "
          f"(+-{rse('b')}), fc {fmt(f['fc'])} N m (+-{rse('fc')}; 1 standard error); "
          f"settled within +-10 % of final at {fmt(st['all'])} s")
    return OK


def add_commands(subparsers: Any) -> None:
    """Register ``estimate`` and ``identify`` on an argparse ``subparsers`` object.

    Each parser gets ``func`` (set_defaults) taking the parsed namespace and
    returning an exit code (:mod:`cosim.cli.exitcodes`): 0 ok, 2 on a bad log / bad
    arguments / I/O error (the message is printed to stderr as ``cosim: error:
    ...``; nothing is written), 4 when the log cannot tell (``identify``:
    ``cannot_identify``, ``estimate``: ``cannot_judge``; the result is written and
    says why).
    """
    e = subparsers.add_parser(
        "estimate", help="run the aaKF and encoder differencing over a ballscrew-1dof log",
        description="Run the aaKF (thesis Sec. 2.2) and encoder differencing over a "
                    "ballscrew-1dof trial log; write the estimates as CSV.")
    e.add_argument("--log", required=True, help="trial log (stem, .csv or .json)")
    e.add_argument("--out", required=True, help="output CSV")
    e.add_argument("--sigma-a", type=float, default=None, dest="sigma_a",
                   help="motor-jerk process noise [rad/s^3/sqrt(Hz)] of a single filter "
                        "(default: the sigma_a bank, weighed by the data)")
    e.add_argument("--sigma-b", type=float, default=None, dest="sigma_b",
                   help="bias random-walk intensity [(m/s^2)/sqrt(s)] (default 1e-3)")
    e.add_argument("--burn-in", type=float, default=1.0, dest="burn_in", metavar="S",
                   help="start-up transient excluded from the innovation whiteness tests [s] "
                        "(default 1; too few samples after it: the verdict is cannot_judge)")
    e.set_defaults(func=_cmd_estimate)
    i = subparsers.add_parser(
        "identify", help="RLS identification of J, b, fc from a ballscrew-1dof log",
        description="RLS identification (thesis Sec. 2.3) of J, b, fc from a "
                    "ballscrew-1dof trial log; write the estimates as JSON.")
    i.add_argument("--log", required=True, help="trial log (stem, .csv or .json)")
    i.add_argument("--out", required=True, help="output JSON")
    i.add_argument("--speed", choices=("aakf", "encoder"), default="aakf",
                   help="speed fed to the RLS (default aakf)")
    i.add_argument("--sigma-a", type=float, default=None, dest="sigma_a",
                   help="aaKF motor-jerk process noise of a single filter for --speed aakf "
                        "[rad/s^3/sqrt(Hz)] (default: the sigma_a bank, weighed by the data)")
    i.add_argument("--sigma-b", type=float, default=None, dest="sigma_b",
                   help="aaKF bias random-walk intensity for --speed aakf [(m/s^2)/sqrt(s)] (default 1e-3)")
    i.set_defaults(func=_cmd_identify)
