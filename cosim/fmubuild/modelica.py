"""Modelica front end: source scan, flattening with pymoca, and the explicit ODE.

The output of :func:`load_model` is a :class:`FlatModel`: every variable with its
metadata (unit, description, causality, start, min/max) and CasADi SX functions of
an explicit ODE. The subset accepted is documented in ``docs/modelica-subset.md``.
"""
from __future__ import annotations

import dataclasses
import hashlib
import io
import re
import contextlib
from pathlib import Path
from typing import Optional

import casadi as ca
import numpy as np


class ModelicaError(Exception):
    """A model that our build cannot turn into an FMU. Names the model, file, line."""

    def __init__(self, model: str, message: str, file: Optional[Path] = None,
                 line: Optional[int] = None):
        self.model, self.file, self.line = model, file, line
        where = ""
        if file is not None:
            where = f" ({file}" + (f":{line}" if line else "") + ")"
        super().__init__(f"model {model}{where}: {message}")


# Constructs outside the subset: pymoca would reject most of them with an
# exception that names no line, or (worse) silently mis-handle them.
_UNSUPPORTED = [
    (re.compile(r"\bwhen\b"), "'when' clauses are not supported (use the __RehabSim "
                              "sample/noise annotation, docs/modelica-subset.md)"),
    (re.compile(r"^\s*algorithm\b"), "'algorithm' sections are not supported"),
    (re.compile(r"\binitial\s+equation\b"), "'initial equation' is not supported "
                                            "(use start values with fixed = true)"),
    (re.compile(r"\b(pre|edge|sample|reinit|noEvent|smooth|delay|change|initial|terminal)\s*\("),
     "operator '{0}' is not supported"),
    (re.compile(r"\bexternal\b"), "external functions are not supported"),
    (re.compile(r"\bflow\b"), "flow variables / acausal connectors are not supported"),
]

_ANNOT = re.compile(
    r"(?P<decl>(?:input\s+)?Real\s+(?P<name>[A-Za-z_]\w*)[^;]*?)"
    r"annotation\s*\(\s*__RehabSim\s*\((?P<args>[^)]*)\)\s*\)\s*;", re.S)


@dataclasses.dataclass
class Discrete:
    """A variable that the FMU updates at event instants (noise draw or sample)."""
    name: str
    kind: str            # 'noise' or 'sample'
    period: str          # parameter name or numeric literal
    source: str = ""     # sampled variable (kind == 'sample')


@dataclasses.dataclass
class Var:
    name: str
    kind: str            # parameter, calculated, input, state, algebraic, discrete
    type: str = "Real"   # Real, Integer, Boolean
    unit: str = ""
    description: str = ""
    start: Optional[float] = None
    min: Optional[float] = None
    max: Optional[float] = None
    nominal: Optional[float] = None
    is_output: bool = False


@dataclasses.dataclass
class FlatModel:
    name: str                       # e.g. RehabSim.BallScrewUnit
    description: str
    files: list[Path]
    source_hash: str
    params: list[Var]               # independent parameters (settable)
    calculated: list[Var]           # parameters bound to expressions of others
    inputs: list[Var]
    states: list[Var]
    algebraics: list[Var]           # includes outputs that are not states
    discretes: list[Var]
    discrete_specs: list[Discrete]
    # CasADi functions, all over (t, x, u, p_all, d) with p_all = params + calculated
    f_calc: ca.Function = None      # p_indep -> p_calc
    f_x0: ca.Function = None        # p_all -> x0
    f_ode: ca.Function = None       # (t,x,u,p,d) -> xdot
    f_jac: ca.Function = None       # (t,x,u,p,d) -> d xdot / d x (dense)
    f_alg: ca.Function = None       # (t,x,u,p,d) -> algebraics
    periods: list[float] = None     # resolved at run time from parameters: index or literal

    @property
    def identifier(self) -> str:
        return self.name.split(".")[-1]

    @property
    def lti(self) -> bool:
        """The ODE is linear time-invariant between events: xdot = A x + b with A and b
        independent of x and of time (they may depend on parameters, inputs and the
        held discrete variables, all constant over an integration interval)."""
        return bool(self.states) and self.f_ode is not None and is_lti(self.f_ode, self.f_jac)

    def all_vars(self) -> list[Var]:
        return (self.params + self.calculated + self.inputs + self.states
                + self.algebraics + self.discretes)


def package_files(package_dir: Path) -> list[Path]:
    files = sorted(Path(package_dir).rglob("*.mo"))
    if not files:
        raise ModelicaError(str(package_dir), "no .mo files found")
    return files


def source_hash(files: list[Path], extra: str = "") -> str:
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    h.update(extra.encode())
    return h.hexdigest()


def _strip_comments(text: str) -> str:
    """Blank out comments and string literals, keeping line structure."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i)); i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j])); i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append('"' + re.sub(r"[^\n]", " ", text[i + 1:j - 1]) + '"'); i = j
        else:
            out.append(c); i += 1
    return "".join(out)


def scan_unsupported(model: str, files: list[Path]) -> None:
    """Raise ModelicaError at the first construct outside the subset."""
    for f in files:
        code = _strip_comments(f.read_text())
        # vendor annotations are ours: blank them so their words do not trigger
        for lineno, line in enumerate(code.splitlines(), 1):
            for rx, msg in _UNSUPPORTED:
                m = rx.search(line)
                if m:
                    raise ModelicaError(model, msg.format(*(m.groups() or ("",))),
                                        f, lineno)


def parse_annotations(files: list[Path]) -> dict[str, dict[str, Discrete]]:
    """Vendor annotations per class: {class_name: {var_name: Discrete}}."""
    result: dict[str, dict[str, Discrete]] = {}
    for f in files:
        text = f.read_text()
        cls = f.stem
        for m in _ANNOT.finditer(_strip_comments_keep_strings(text)):
            args = dict(
                (k.strip(), v.strip().strip('"'))
                for k, v in (a.split("=", 1) for a in _split_args(m.group("args"))))
            line = text[:m.start("name")].count("\n") + 1
            name = m.group("name")
            if "noise" in args:
                if args["noise"] != "gaussian":
                    raise ModelicaError(cls, f"unknown noise kind {args['noise']!r} "
                                        "(only 'gaussian')", f, line)
                kind, source = "noise", ""
            elif "sample" in args:
                kind, source = "sample", args["sample"]
            else:
                raise ModelicaError(cls, "__RehabSim annotation needs noise= or sample=",
                                    f, line)
            if "period" not in args:
                raise ModelicaError(cls, f"__RehabSim annotation of {name} needs period=",
                                    f, line)
            if not m.group("decl").lstrip().startswith("input"):
                raise ModelicaError(cls, f"__RehabSim variable {name} must be declared "
                                    "'input Real'", f, line)
            result.setdefault(cls, {})[name] = Discrete(name, kind, args["period"], source)
    return result


def _strip_comments_keep_strings(text: str) -> str:
    text = re.sub(r"//[^\n]*", lambda m: " " * len(m.group()), text)
    return re.sub(r"/\*.*?\*/", lambda m: re.sub(r"[^\n]", " ", m.group()), text, flags=re.S)


def _split_args(s: str) -> list[str]:
    return [a for a in (x.strip() for x in s.split(",")) if a]


def _pymoca_line_hint(model: str, files: list[Path], exc: Exception):
    """Map a pymoca exception to the source line it most likely concerns."""
    msg = str(exc)
    m = re.search(r"Unknown function (\w+)", msg) or re.search(r"'(\w+)'", msg)
    if m:
        word = m.group(1)
        for f in files:
            for i, line in enumerate(f.read_text().splitlines(), 1):
                if re.search(rf"\b{re.escape(word)}\b", line):
                    return f, i
    m = re.search(r"line (\d+)", msg)
    if m:
        return None, int(m.group(1))
    return None, None


def _flat_symbols(package_dir: Path, model: str, files: list[Path]):
    import pymoca.parser
    import pymoca.tree
    import pymoca.ast

    root = None
    for f in files:
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                tree = pymoca.parser.parse(f.read_text())
        except Exception as exc:  # antlr raises on syntax errors
            raise ModelicaError(model, f"does not parse: {exc}", f,
                                _pymoca_line_hint(model, [f], exc)[1]) from None
        if tree is None or err.getvalue().strip():
            line = re.search(r"line (\d+)", err.getvalue())
            raise ModelicaError(model, "syntax error: " + err.getvalue().strip().splitlines()[0]
                                if err.getvalue().strip() else "syntax error",
                                f, int(line.group(1)) if line else None)
        if root is None:
            root = tree
        else:
            root.extend(tree)
    flat = pymoca.tree.flatten(root, pymoca.ast.ComponentRef.from_string(model))
    cls = list(flat.classes.values())[0]
    return cls


def _num(x) -> Optional[float]:
    v = getattr(x, "value", x)
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, (int, float)):
        return float(v)
    return None


def load_model(package_dir: Path, model: str) -> FlatModel:
    """Flatten ``model`` (e.g. 'RehabSim.BallScrewUnit') into a FlatModel."""
    from pymoca.backends.casadi.api import transfer_model

    package_dir = Path(package_dir)
    files = package_files(package_dir)
    scan_unsupported(model, files)
    annotations = parse_annotations(files)
    try:
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            cls = _flat_symbols(package_dir, model, files)
            m = transfer_model(str(package_dir), model,
                               {"compile": False, "cache": False,
                                "replace_constants": True,
                                "replace_parameter_expressions": False})
    except ModelicaError:
        raise
    except Exception as exc:
        f, line = _pymoca_line_hint(model, files, exc)
        raise ModelicaError(model, f"pymoca failed to flatten it: {exc}", f, line) from None
    if m.initial_equations:
        raise ModelicaError(model, "initial equations are not supported")

    symbols = cls.symbols
    # annotations apply to the model's own top-level declarations and to those of
    # its components (prefixed names)
    comp_types = component_types(files)
    discrete_specs: dict[str, Discrete] = {}
    for name, sym in symbols.items():
        base = name.split(".")[-1]
        owner = _owner_class(comp_types, name, model)
        spec = annotations.get(owner, {}).get(base)
        if spec is not None:
            prefix = name[: -len(base)]
            discrete_specs[name] = Discrete(name, spec.kind, spec.period,
                                            prefix + spec.source if spec.source else "")

    def meta(name: str, kind: str, python_type=float) -> Var:
        sym = symbols.get(name)
        typ = {int: "Integer", bool: "Boolean"}.get(python_type, "Real")
        v = Var(name=name, kind=kind, type=typ)
        if sym is not None:
            v.description = (sym.comment or "").strip()
            u = getattr(sym.unit, "value", None)
            v.unit = u if isinstance(u, str) else ""
            v.min = _num(sym.min); v.max = _num(sym.max)
            v.nominal = _num(sym.nominal)
            v.start = _num(sym.start)
        return v

    outputs = set(m.outputs)
    params, calculated = [], []
    p_syms = []
    for pv in m.parameters:
        name = pv.symbol.name()
        val = pv.value
        var = meta(name, "parameter", pv.python_type)
        if isinstance(val, (int, float, bool)) or (isinstance(val, ca.MX) and val.is_constant()):
            var.start = float(val) if not isinstance(val, ca.MX) else float(ca.evalf(val))
            params.append(var)
        elif isinstance(val, ca.MX):
            var.kind = "calculated"
            var.start = None
            calculated.append((var, val))
        else:
            raise ModelicaError(model, f"parameter {name} has no value")
        p_syms.append(pv.symbol)
    calc_vars = [v for v, _ in calculated]

    inputs, discretes = [], []
    for iv in m.inputs:
        name = iv.symbol.name()
        if name in discrete_specs:
            var = meta(name, "discrete"); var.start = var.start or 0.0
            discretes.append((var, iv.symbol))
        else:
            var = meta(name, "input")
            if var.start is None:
                var.start = _num(iv.start) if _num(iv.start) is not None else 0.0
            inputs.append((var, iv.symbol))
    # a component's annotated input (e.g. the noise of a load cell inside a rig) is
    # not a top-level input for pymoca, it appears as an algebraic unknown without an
    # equation: the annotation is what defines it, so it becomes a discrete too
    nested_discrete = set()
    for av in m.alg_states:
        name = av.symbol.name()
        if name in discrete_specs and "." in name:
            var = meta(name, "discrete"); var.start = var.start or 0.0
            discretes.append((var, av.symbol))
            nested_discrete.add(name)
    for name in discrete_specs:
        if name not in [v.name for v, _ in discretes]:
            raise ModelicaError(model, f"__RehabSim variable {name} is not an input of the model")

    states = []
    for sv in m.states:
        var = meta(sv.symbol.name(), "state")
        var.is_output = var.name in outputs
        states.append((var, sv.symbol, sv.start))
    algs = []
    for av in m.alg_states:
        if av.symbol.name() in nested_discrete:
            continue
        var = meta(av.symbol.name(), "algebraic")
        var.is_output = var.name in outputs
        var.start = None
        algs.append((var, av.symbol))
    for v, _, _ in states:
        v.start = None

    # --- the explicit ODE: residual r(xdot, z; x, u, p, d, t) = 0, linear in (xdot, z)
    t = m.time
    x_mx = [s for _, s, _ in states]
    xd_mx = [d.symbol for d in m.der_states]
    z_mx = [s for _, s in algs]
    u_mx = [s for _, s in inputs]
    d_mx = [s for _, s in discretes]
    all_in = [t] + x_mx + xd_mx + z_mx + u_mx + p_syms + d_mx
    res_mx = ca.vertcat(*m.equations) if m.equations else ca.MX(0, 1)
    n_unknown = len(xd_mx) + len(z_mx)
    if res_mx.numel() != n_unknown:
        raise ModelicaError(model, f"system is not balanced: {res_mx.numel()} equations for "
                            f"{n_unknown} unknowns (derivatives + algebraic variables)")
    F = ca.Function("F", all_in, [res_mx]).expand()
    T = ca.SX.sym("time")
    X = [ca.SX.sym(v.name) for v, _, _ in states]
    XD = [ca.SX.sym(f"der({v.name})") for v, _, _ in states]
    Z = [ca.SX.sym(v.name) for v, _ in algs]
    U = [ca.SX.sym(v.name) for v, _ in inputs]
    P = [ca.SX.sym(v.symbol.name()) for v in m.parameters]
    D = [ca.SX.sym(v.name) for v, _ in discretes]
    r = F(T, *X, *XD, *Z, *U, *P, *D)
    w = ca.vertcat(*XD, *Z)
    sol = _causalise(model, r, w, [str(e) for e in m.equations],
                     [f"der({v.name})" for v, _, _ in states] + [v.name for v, _ in algs])
    xdot = sol[: len(XD)]
    zval = sol[len(XD):]

    # parameter vector order: independent first, then calculated
    p_index = {v.symbol.name(): i for i, v in enumerate(m.parameters)}
    P_ind = [P[p_index[v.name]] for v in params]
    P_calc = [P[p_index[v.name]] for v in calc_vars]
    P_all = P_ind + P_calc
    # calculated parameters may depend on each other: substitute to a fixed point
    Fp = ca.Function("Fp", p_syms, [ca.vertcat(*[e for _, e in calculated])] if calculated
                     else [ca.MX(0, 1)]).expand()
    calc_expr = Fp(*P)
    for _ in range(len(calc_vars) + 1):
        calc_expr = ca.substitute(calc_expr, ca.vertcat(*P_calc) if P_calc else ca.SX(0, 1),
                                  calc_expr) if P_calc else calc_expr
    if P_calc and ca.depends_on(calc_expr, ca.vertcat(*P_calc)):
        raise ModelicaError(model, "cyclic parameter bindings")
    f_calc = ca.Function("calc", [ca.vertcat(*P_ind)], [calc_expr] if P_calc else [ca.SX(0, 1)])

    # start values of states: numbers or parameter expressions
    x0 = []
    for (v, sym, start) in states:
        if isinstance(start, ca.MX):
            fs = ca.Function("s", p_syms, [start]).expand()
            x0.append(fs(*P))
        else:
            val = _num(start)
            x0.append(ca.SX(val if val is not None else 0.0))
    f_x0 = ca.Function("x0", [ca.vertcat(*P_all)], [ca.vertcat(*x0)])

    args = [T, ca.vertcat(*X), ca.vertcat(*U), ca.vertcat(*P_all), ca.vertcat(*D)]
    names = ["t", "x", "u", "p", "d"]
    f_ode = ca.Function("ode", args, [xdot], names, ["xdot"])
    f_jac = ca.Function("jacobian_x", args, [ca.densify(ca.jacobian(xdot, ca.vertcat(*X))),
                                       ca.densify(ca.jacobian(xdot, T))],
                        names, ["J", "dfdt"])
    f_alg = ca.Function("alg", args, [zval], names, ["z"])

    # resolve discrete specs: period must name an independent parameter or be a number
    specs = []
    pnames = [v.name for v in params]
    known = {v.name for v in params + calc_vars} | {v.name for v, _, _ in states} \
        | {v.name for v, _ in algs} | {v.name for v, _ in inputs} | {v.name for v, _ in discretes}
    for v, _ in discretes:
        spec = discrete_specs[v.name]
        prefix = v.name[: len(v.name) - len(v.name.split(".")[-1])]
        per = spec.period
        if _is_number(per):
            pass
        elif per in pnames:
            pass
        elif prefix + per in pnames:
            per = prefix + per
        else:
            raise ModelicaError(model, f"period {spec.period!r} of {v.name} is neither a "
                                "number nor an independent parameter")
        if spec.kind == "sample" and spec.source not in known:
            raise ModelicaError(model, f"{v.name} samples unknown variable {spec.source!r}")
        specs.append(Discrete(v.name, spec.kind, per, spec.source))
    if any(s.kind == "noise" for s in specs) and "seed" not in pnames:
        raise ModelicaError(model, "a model with noise must declare 'parameter Integer seed'")

    desc = (getattr(cls, "comment", "") or "").strip()
    return FlatModel(
        name=model, description=desc or model, files=files,
        source_hash=source_hash(files, model),
        params=params, calculated=calc_vars, inputs=[v for v, _ in inputs],
        states=[v for v, _, _ in states], algebraics=[v for v, _ in algs],
        discretes=[v for v, _ in discretes], discrete_specs=specs,
        f_calc=f_calc, f_x0=f_x0, f_ode=f_ode, f_jac=f_jac, f_alg=f_alg)


_AFFINE_OPS = {ca.OP_ADD, ca.OP_SUB, ca.OP_NEG, ca.OP_ASSIGN, ca.OP_TWICE}


def _structurally_affine(f: ca.Function, i_var: int) -> bool:
    """True if every output of the SX function ``f`` is affine in its input ``i_var``:
    walking f's instructions, the input only passes through +, -, negation and
    products/quotients with factors that do not depend on it. No false positives
    (unlike a Jacobian test, which floor/ceil/sign of the input would pass)."""
    dep = {}                            # work index -> depends on input i_var
    for k in range(f.n_instructions()):
        op, ins, outs = f.instruction_id(k), f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_OUTPUT:
            continue
        if op == ca.OP_INPUT:
            dep[outs[0]] = ins[0] == i_var
            continue
        if op in (ca.OP_CONST, ca.OP_PARAMETER):
            dep[outs[0]] = False
            continue
        d = [dep.get(j, False) for j in ins]
        if any(d):
            if op in _AFFINE_OPS:
                pass
            elif op == ca.OP_MUL and not (d[0] and d[1]):
                pass
            elif op == ca.OP_DIV and not d[1]:
                pass
            else:
                return False
        for o in outs:
            dep[o] = any(d)
    return True


def is_lti(f_ode: ca.Function, f_jac: ca.Function) -> bool:
    """Is xdot = f(t, x, u, p, d) affine in x with df/dx independent of x and t and no
    explicit dependence on t?  (The Jacobian tests as CasADi's depends_on, confirmed
    by a structural walk of f, since a Jacobian of floor(x) is zero.)"""
    if not (f_ode.is_a("SXFunction") and f_jac.is_a("SXFunction")):
        return False
    t, x = f_ode.sx_in(0), f_ode.sx_in(1)
    if x.numel() == 0:
        return False
    xdot = f_ode.call(f_ode.sx_in())[0]
    J, _ = f_jac.call(f_jac.sx_in())
    J = ca.substitute(J, ca.vertcat(f_jac.sx_in(0), f_jac.sx_in(1)), ca.vertcat(t, x))
    if ca.depends_on(xdot, t) or ca.depends_on(J, x) or ca.depends_on(J, t):
        return False
    return _structurally_affine(f_ode, 1)


def _causalise(model: str, r: ca.SX, w: ca.SX, eq_text: list[str], w_names: list[str]) -> ca.SX:
    """Solve r(w) = 0 for w block by block (block-triangular form).

    Each block must be linear in its own unknowns once the unknowns of earlier
    blocks are substituted (explicit assignments, aliases, and linear algebraic
    loops such as J*der(w) = ... with a bristle-damping term); its matrix may depend
    on states, inputs and parameters.
    """
    n = w.numel()
    if n == 0:
        return ca.SX(0, 1)
    sp = ca.jacobian(r, w).sparsity()
    if ca.sprank(sp) < n:
        raise ModelicaError(model, "structurally singular system: some derivative or "
                            "algebraic variable is determined by no equation")
    nb, rowperm, colperm, rowblock, colblock, _, _ = sp.btf()
    blocks = [([rowperm[i] for i in range(rowblock[k], rowblock[k + 1])],
               [colperm[i] for i in range(colblock[k], colblock[k + 1])]) for k in range(nb)]
    solved: dict[int, ca.SX] = {}
    pending = list(blocks)
    while pending:
        progress = False
        for blk in list(pending):
            rows, cols = blk
            rb = ca.vertcat(*[r[i] for i in rows])
            if solved:
                keys = sorted(solved)
                rb = ca.substitute(rb, ca.vertcat(*[w[k] for k in keys]),
                                   ca.vertcat(*[solved[k] for k in keys]))
            others = [k for k in range(n) if k not in cols and k not in solved]
            if others and ca.depends_on(rb, ca.vertcat(*[w[k] for k in others])):
                continue  # needs a block not solved yet
            wb = ca.vertcat(*[w[k] for k in cols])
            Ab = ca.jacobian(rb, wb)
            if ca.depends_on(Ab, wb):
                raise ModelicaError(model, "equation(s) nonlinear in the variable they "
                                    "determine (nonlinear algebraic loop, not supported): "
                                    + "; ".join(eq_text[i] for i in rows[:3])
                                    + " -> " + ", ".join(w_names[k] for k in cols))
            bb = -ca.substitute(rb, wb, ca.DM.zeros(wb.shape))
            _check_affine(model, rb, wb, Ab, bb, [eq_text[i] for i in rows],
                          [w_names[k] for k in cols])
            xb = ca.solve(Ab, bb) if len(cols) > 1 else bb / Ab
            for j, k in enumerate(cols):
                solved[k] = xb[j]
            pending.remove(blk)
            progress = True
        if not progress:
            raise ModelicaError(model, "cannot order the equations (algebraic loop across "
                                "blocks): " + ", ".join(w_names[k] for b in pending for k in b[1]))
    return ca.vertcat(*[solved[k] for k in range(n)])


def _check_affine(model, rb, wb, Ab, bb, eqs, names, trials: int = 4) -> None:
    """Numerically confirm rb(wb) == Ab wb - bb at random points.

    The structural test (Jacobian independent of wb) misses piecewise-constant
    functions such as floor() of an unknown, whose derivative is zero but which is
    not affine: a linear solve would then be silently wrong.
    """
    syms = ca.symvar(ca.vertcat(rb, Ab, bb))
    others = [s for s in syms if not ca.depends_on(wb, s)]
    f = ca.Function("affine_check", [wb] + others, [rb - (ca.mtimes(Ab, wb) - bb)])
    rng = np.random.default_rng(0)
    for _ in range(trials):
        args = [rng.uniform(-3, 3, wb.shape)] + [rng.uniform(0.5, 3) for _ in others]
        dev = np.abs(np.array(f(*args), dtype=float)).max(initial=0.0)
        if not np.isfinite(dev):
            continue
        if dev > 1e-8 * (1 + np.abs(np.array(ca.Function("s", [wb] + others, [rb])(*args),
                                              dtype=float)).max(initial=0.0)):
            raise ModelicaError(model, "equation(s) not affine in the variable(s) they determine "
                                "(e.g. floor/abs/sign/if of an algebraic variable; apply them to "
                                "states, inputs or held samples): " + "; ".join(eqs[:3])
                                + " -> " + ", ".join(names))


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


_BUILTIN = {"Real", "Integer", "Boolean", "String", "parameter", "input", "output",
            "constant", "final", "model", "package", "within", "end", "equation",
            "extends", "import", "discrete", "protected", "public", "annotation"}
_COMP = re.compile(r"^\s*(?:final\s+)?(?:[A-Za-z_]\w*\.)*([A-Z]\w*)\s+([a-zA-Z_]\w*)\s*[(;\"]",
                   re.M)


def component_types(files: list[Path]) -> dict[str, dict[str, str]]:
    """{class: {component: class of the component}} from the declarations."""
    out: dict[str, dict[str, str]] = {}
    for f in files:
        code = _strip_comments(f.read_text())
        for m in _COMP.finditer(code):
            typ, comp = m.group(1), m.group(2)
            if typ in _BUILTIN or comp in _BUILTIN:
                continue
            out.setdefault(f.stem, {})[comp] = typ
    return out


def _owner_class(comp_types: dict, name: str, model: str) -> str:
    """Class (file stem) that declares the flat variable ``name``."""
    owner = model.split(".")[-1]
    for part in name.split(".")[:-1]:
        owner = comp_types.get(owner, {}).get(part, owner)
    return owner
