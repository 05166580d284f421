"""``cosim gap diagnose``: the sim-to-real gap diagnosis command (``spec/gap-diagnosis.md``);
``cosim gap draft-binding``: a first binding file of a user's plant FMU to their logs."""
from __future__ import annotations

import sys
from typing import Any

from .exitcodes import BAD_INPUT, CANNOT_TELL, FAILED, OK

__all__ = ["add_commands"]


def _progress(msg: str) -> None:
    """One line on stderr, overwritten (a terminal) or appended (a file)."""
    if sys.stderr.isatty():
        print(f"\r\x1b[K{msg}", end="", file=sys.stderr, flush=True)
    else:
        print(msg, file=sys.stderr, flush=True)


def _cmd_diagnose(a: Any) -> int:
    from ..gap.device import GapInputError
    from ..gap.diagnose import diagnose
    from ..gap.plausibility import Implausible, write_refusal
    from ..logs.fileio import OutputPathError, check_out_dir
    try:
        check_out_dir(a.out)        # created by diagnose once the inputs are read
        if (a.plant is None) == (a.device is None):
            raise GapInputError("give either --device NAME (a built-in device) or --plant PLANT.fmu "
                                "with --binding BINDING.yaml")
        if a.plant is not None:
            if a.binding is None:
                raise GapInputError("--plant needs --binding BINDING.yaml (which log column is which FMU variable)")
            from ..gap.diagnose import diagnose_plant
            res = diagnose_plant(a.plant, a.binding, a.fit, a.test, a.out, report=not a.no_report,
                                 margin=a.margin, progress=_progress)
        else:
            res = diagnose(a.device, a.fit, a.test, a.out, report=not a.no_report, margin=a.margin)
    except (GapInputError, OutputPathError) as e:
        print(f"cosim: error: {e}", file=sys.stderr)
        return BAD_INPUT
    except Implausible as e:        # the logs do not fit the nominal model: no diagnosis
        print(f"cannot diagnose: implausible input: {e}")
        write_refusal(a.out, a.device or str(a.plant), e)
        return CANNOT_TELL
    for w in res.get("warnings") or ():
        print(f"warning: {w}", file=sys.stderr)
    if res.get("cannot_diagnose"):
        print(f"cannot diagnose: {res['cannot_diagnose']}")
    else:
        g = res["gap"]
        print(f"selected: {res['selected']}  gap ({g['metric']}) on the test logs: "
              f"{g['test_before']:.4g} -> {g['test_after']:.4g}")
    print(f"wrote {a.out}/diagnosis.json" + ("" if a.no_report else f" and {a.out}/report.html"))
    return CANNOT_TELL if res.get("cannot_diagnose") else OK


def _cmd_draft_binding(a: Any) -> int:
    from ..gap.binding_draft import write_draft
    from ..gap.device import GapInputError
    try:
        out, problem = write_draft(a.plant, a.log, a.out, overwrite=a.force)
    except GapInputError as e:
        print(f"cosim: error: {e}", file=sys.stderr)
        return BAD_INPUT
    if problem:
        print(f"wrote {out}, but it does not check yet (complete it from the datasheet): {problem}")
        return FAILED
    print(f"wrote {out}: it checks against {a.plant} and the {len(a.log)} logs; "
          "CHECK every field against the datasheet before `cosim gap diagnose --plant`")
    return OK


def add_commands(subparsers: Any) -> None:
    """Register ``cosim gap diagnose`` (exit 0: diagnosed; 2: bad input, message on
    stderr; 4: the logs cannot tell, ``cannot_diagnose`` in diagnosis.json)."""
    g = subparsers.add_parser("gap", help="sim-to-real gap diagnosis")
    gsub = g.add_subparsers(dest="gap_cmd", required=True)
    d = gsub.add_parser(
        "diagnose", help="where the sim-to-real gap lies, which effect causes it, how far it shrinks",
        description="Recalibrate the nominal model on --fit logs, localise the residual, rank and fit "
                    "the catalogue effects, select those that lower the gap on held-out data, and "
                    "measure the gap on --test logs before/after. Writes DIR/diagnosis.json and "
                    "DIR/report.html.")
    d.add_argument("--device", default=None,
                   help="a built-in device, e.g. ballscrew-1dof (an unknown name is "
                        "refused with the list of known ones); or --plant/--binding")
    d.add_argument("--plant", default=None, metavar="PLANT.fmu",
                   help="your own plant FMU (FMI 2.0 with Model Exchange), instead of --device")
    d.add_argument("--binding", default=None, metavar="BINDING.yaml",
                   help="with --plant: which log column drives/measures which FMU variable "
                        "(format gap-binding/1, docs/gap-plant-diagnosis.md)")
    d.add_argument("--fit", nargs="+", required=True, metavar="LOG", help="trial logs to fit on (.csv or stem)")
    d.add_argument("--test", nargs="+", required=True, metavar="LOG", help="held-out trial logs")
    d.add_argument("--out", required=True, metavar="DIR", help="output directory")
    d.add_argument("--margin", type=float, default=None,
                   help="minimum held-out reduction of the gap energy to select an effect (default: the device's chosen value, cosim/gap/thresholds.json)")
    d.add_argument("--no-report", action="store_true", help="skip report.html")
    d.set_defaults(func=_cmd_diagnose, heartbeat=True)
    b = gsub.add_parser(
        "draft-binding", help="draft a binding file of your plant FMU to your logs (to check, then diagnose)",
        description="Write a first gap-binding/1 file for --plant from its modelDescription and the logs' "
                    "sidecars: roles matched by dimension and name, sensor figures from the sidecars (or the "
                    "samples), recalibrated parameters within +-25 %%. Each guess is commented; check them "
                    "against the datasheet. Exit 0: the draft checks against the FMU and the logs; 1: written "
                    "but incomplete (the message names the field); 2: an FMU or log cannot be read.")
    b.add_argument("--plant", required=True, metavar="PLANT.fmu", help="your plant FMU")
    b.add_argument("--log", nargs="+", required=True, metavar="LOG", help="trial logs of the device (.csv or stem)")
    b.add_argument("--out", required=True, metavar="BINDING.yaml", help="the binding file to write")
    b.add_argument("--force", action="store_true", help="replace --out if it exists")
    b.set_defaults(func=_cmd_draft_binding)
