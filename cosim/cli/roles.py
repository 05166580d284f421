"""``cosim roles [NAME]``: the role contracts an FMU can play (docs/bring-your-own-fmu.md)."""
from __future__ import annotations

from . import exitcodes as ec
from .exitcodes import CliError


def _cmd_roles(a) -> int:
    """Print each role contract (or the one named): its variables, their causality,
    unit and meaning: what an FMU must offer, directly or through a role binding
    (docs/bring-your-own-fmu.md)."""
    from ..fmi.fmu import suggest
    from ..master.roles import CONTRACTS
    names = [a.name] if a.name else list(CONTRACTS)
    if a.name and a.name not in CONTRACTS:
        close = suggest(a.name, CONTRACTS)
        raise CliError(f"unknown role contract {a.name!r}"
                       + (f"; did you mean {', '.join(map(repr, close))}?" if close else "")
                       + f" (contracts: {', '.join(CONTRACTS)})")
    for k, name in enumerate(names):
        c = CONTRACTS[name]
        from ..master.binding import role_parameters      # a binding maps these too
        rows = c.variables() + [(n, "parameter", u, m)
                                for n, (u, m) in role_parameters(c).items()]
        w = max(len(n) for n, *_ in rows)
        wu = max(len(u or "1") for _, _, u, _ in rows)
        if k:
            print()
        print(f"{c.name}: {c.description}")
        print(f"  {'variable':{w}s}  causality  {'unit':{wu}s}  meaning")
        for n, caus, u, meaning in rows:
            print(f"  {n:{w}s}  {caus:9s}  {u or '1':{wu}s}  {meaning}")
    if not a.name:
        print("\nAn FMU with other names or units plays a role through a binding "
              "(map/units; docs/bring-your-own-fmu.md).")
    return ec.OK


def add_commands(sub) -> None:
    ro = sub.add_parser("roles", help="the role contracts: variables, causality, unit, meaning")
    ro.add_argument("name", nargs="?", help="one contract (default: all)")
    ro.set_defaults(func=_cmd_roles)
