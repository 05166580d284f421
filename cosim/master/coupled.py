"""Coupled groups of a System: FMUs joined by a stiff element, solved together.

``System.couple("unit", "cell", "partner")`` declares that the three roles form one
strongly coupled system (a 2e4-2e5 N/m load cell or wall between two units cannot be
exchanged explicitly at 1 ms). The members run as Model Exchange FMUs and are
integrated by one implicit solver (:class:`cosim.fmi.me_group.MEGroup`); every
connection between two members of the group is continuous inside it (not exchanged
at the step); connections from or to anything else keep the master's timing
(:mod:`cosim.master.system`): inputs from outside are held over the step, outputs are
read at the ticks. The group is stepped once per tick, at the position of its last
member in the role order.
"""
from __future__ import annotations

from ..fmi.fmu import FMUError


def group_of(system, role: str):
    """The coupled group (tuple of roles) ``role`` belongs to, or None."""
    for g in system.coupled:
        if role in g:
            return g
    return None


def is_internal(system, conn) -> bool:
    """A connection between two members of the same coupled group."""
    g = group_of(system, conn.source.partition(".")[0])
    return g is not None and conn.dest.partition(".")[0] in g


def check(system, error):
    """The groups can run: members bound, Model Exchange, no sequential connection
    inside a group, none from a member to a role stepped before the group.
    ``error(msg)`` builds the exception."""
    order = list(system.roles)
    for g in system.coupled:
        for r in g:
            if r not in system.roles:
                raise error(f"coupled group {list(g)}: role {r!r} is not bound")
            sl = system.roles[r]
            if sl.kind != "me":
                raise error(f"coupled group {list(g)}: role {r!r} runs as Co-Simulation; a "
                            f"member of a coupled group must run as Model Exchange "
                            f"(add it with kind='me'; {sl.path.name} "
                            + ("has a Model Exchange interface)" if sl.md.modelExchange
                               is not None else "has no Model Exchange interface)"))
        last = max(order.index(r) for r in g)
        for c in system._connections:
            s, d = c.source.partition(".")[0], c.dest.partition(".")[0]
            if not c.sequential:
                continue
            if s in g and d in g:
                raise error(f"connection {c.source} -> {c.dest}: sequential inside the "
                            f"coupled group {list(g)} (a connection inside a group is "
                            f"continuous; drop 'sequential')")
            if s in g and order.index(d) < last:
                raise error(f"sequential connection {c.source} -> {c.dest}: the coupled "
                            f"group {list(g)} is stepped at its last member "
                            f"{order[last]!r}; role {d!r} must be added after it")


def start(system, T0: float, error) -> list:
    """Build the groups' integrators after every FMU left initialisation (the members'
    own MEIntegrators exist and have done their initial event iteration). Returns the
    :class:`~cosim.fmi.me_group.MEGroup` objects (the members' steps now go through
    them). ``error(msg)`` builds the exception for a group that cannot be solved
    (an algebraic loop)."""
    from ..fmi.me_group import GroupError, Link, MEGroup
    out = []
    for g in system.coupled:
        roles = [r for r in system.roles if r in g]       # the master's order
        slaves = [system.roles[r] for r in roles]
        links = []
        for c in system._connections:
            if not is_internal(system, c) or c.source.partition(".")[0] not in roles:
                continue
            s_role, _, s_var = c.source.partition(".")
            d_role, _, d_var = c.dest.partition(".")
            sv = system.roles[s_role].var(s_var)
            dv = system.roles[d_role].var(d_var)
            if sv.type != "Real" or dv.type != "Real" or sv.shape or dv.shape:
                raise FMUError(f"connection {c.source} -> {c.dest}: inside the coupled group "
                               f"{list(g)} only scalar Real variables can be connected")
            links.append(Link(roles.index(s_role), sv.vr, roles.index(d_role), dv.vr,
                              c.gain, c.unit_offset, f"{c.source} -> {c.dest}"))
        last = slaves[-1]
        try:
            out.append(MEGroup([s.me_integrator for s in slaves], roles, links, last.error, T0,
                               rtol=min(s.rtol for s in slaves), error_type=FMUError))
        except GroupError as exc:
            raise error(str(exc)) from None
    return out
