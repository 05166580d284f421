"""Probe FMUs for the tests: small FMI 1.0 / 2.0 / 3.0 FMUs written in C in a test,
compiled with gcc against the FMI headers that FMPy ships (not the project's wrapper),
packaged in a temporary folder.

A probe can trace every FMI call it receives: C sources that include
:data:`TRACE_C` get ``trace("fmi2SetReal vr=%u v=%g", ...)``, which appends one line
per call to the file named by the environment variable ``PROBE_TRACE`` (nothing when it
is unset); :func:`read_trace` returns the lines. Tests assert the call sequences the
FMI standard allows and compare results with FMPy on the same FMU.

Usage::

    fmu = compile_fmu(tmp_path, "probe", C_SOURCE, MODEL_DESCRIPTION, fmi_version="2.0")

The C source defines the functions the probe implements; every other function of the
FMI version (FMPy resolves them all when it loads a binary) is stubbed to return
``Error`` (3), so a master that calls an unexpected function sees an error status.
"""
from __future__ import annotations

import inspect
import platform
import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

#: ``trace(fmt, ...)``: one line per FMI call into $PROBE_TRACE (appended, flushed).
TRACE_C = r"""
#include <stdio.h>
#include <stdlib.h>
#include <stdarg.h>
static void trace(const char *fmt, ...) {
    const char *path = getenv("PROBE_TRACE");
    if (!path) return;
    FILE *f = fopen(path, "a");
    if (!f) return;
    va_list ap; va_start(ap, fmt); vfprintf(f, fmt, ap); va_end(ap);
    fputc('\n', f);
    fclose(f);
}
"""

_PLATFORM_DIR = {"1.0": "linux64", "2.0": "linux64", "3.0": "x86_64-linux"}


def fmi_headers_dir() -> Path:
    """The folder of FMPy's FMI 1/2/3 C headers (``fmi2Functions.h``...)."""
    import fmpy
    return Path(fmpy.__file__).parent / "c-code"


def _needed_functions(fmi_version: str, model_identifier: str) -> set[str]:
    """Every C function FMPy's classes of this FMI version resolve from the binary."""
    if fmi_version == "1.0":
        from fmpy.fmi1 import FMU1Model, FMU1Slave
        names = set()
        for cls in (FMU1Model, FMU1Slave):
            names |= {n for n, _ in inspect.getmembers(cls) if re.match(r"fmi1[A-Z]", n)}
        return {f"{model_identifier}_{n.replace('fmi1', 'fmi', 1)}" for n in names}
    if fmi_version == "2.0":
        from fmpy.fmi2 import FMU2Model, FMU2Slave
        classes, pattern = (FMU2Model, FMU2Slave), r"fmi2[A-Z]"
    elif fmi_version == "3.0":
        from fmpy.fmi3 import FMU3Model, FMU3Slave
        classes, pattern = (FMU3Model, FMU3Slave), r"fmi3[A-Z]"
    else:
        raise ValueError(f"fmi_version must be '1.0', '2.0' or '3.0', not {fmi_version!r}")
    names = set()
    for cls in classes:
        names |= {n for n, _ in inspect.getmembers(cls) if re.match(pattern, n)}
    return names


def compile_fmu(out_dir, model_identifier: str, c_source: str, model_description: str,
                fmi_version: str = "2.0", name: str | None = None,
                extra_files: dict[str, bytes | str] | None = None) -> Path:
    """Compile ``c_source`` into ``<out_dir>/<name or model_identifier>.fmu``.

    Parameters
    ----------
    out_dir : path
        Folder for the source, the shared library and the FMU (a test's tmp_path).
    model_identifier : str
        The binary's name (and, for FMI 1.0, the functions' prefix ``<id>_fmi...``).
    c_source : str
        The FMU's C code; it includes the headers it needs (``fmi2Functions.h``,
        ``fmi3Functions.h``, ``fmi1Functions.h`` from :func:`fmi_headers_dir`, on the
        include path; FMPy's ``fmi1Functions.h`` needs ``#include <stddef.h>`` before
        it) and :data:`TRACE_C` if it traces.
    model_description : str
        The ``modelDescription.xml`` text, written as given.
    fmi_version : {"1.0", "2.0", "3.0"}
        Decides the platform folder and which unimplemented functions get stubs.
    extra_files : dict, optional
        More archive members, ``{"resources/x.txt": content}``.

    Returns
    -------
    Path
        The ``.fmu`` file.
    """
    if platform.system() != "Linux" or platform.machine() != "x86_64":
        pytest.skip("probe FMUs are packaged for x86_64 Linux only")
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler to build the probe FMU")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = name or model_identifier
    defined = set(re.findall(r"^[^\s/#].*?\b(\w*fmi[123]?\w+)\s*\(", c_source, re.M))
    missing = sorted(_needed_functions(fmi_version, model_identifier) - defined)
    # unexpected calls get Error (3) or a NULL instance: never silently OK
    stubs = ""
    for n in missing:
        if re.search(r"Instantiate", n):
            stubs += f"void *{n}() {{ return 0; }}\n"
        elif re.search(r"(GetVersion|TypesPlatform)$", n):
            text = {"1.0": "1.0", "2.0": "2.0", "3.0": "3.0"}[fmi_version]
            if "Platform" in n:
                text = "standard32" if fmi_version == "1.0" else "default"
            stubs += f'const char *{n}() {{ return "{text}"; }}\n'
        else:
            stubs += f"int {n}() {{ return 3; }}\n"
    src = out / f"{stem}.c"
    src.write_text(c_source)
    # the stubs live in their own file: it includes no FMI header, so their
    # K&R-style declarations do not clash with the headers' prototypes
    stub_src = out / f"{stem}_stubs.c"
    stub_src.write_text("/* functions this probe does not implement */\n" + stubs)
    so = out / f"{model_identifier}.so"
    p = subprocess.run([cc, "-shared", "-fPIC", "-O1", "-w", f"-I{fmi_headers_dir()}",
                        "-o", str(so), str(src), str(stub_src), "-lm"],
                       capture_output=True, text=True)
    if p.returncode != 0:
        raise AssertionError(f"gcc failed on {src}:\n{p.stderr[:4000]}")
    path = out / f"{stem}.fmu"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("modelDescription.xml", model_description)
        z.write(so, f"binaries/{_PLATFORM_DIR[fmi_version]}/{model_identifier}.so")
        for member, content in (extra_files or {}).items():
            z.writestr(member, content)
    return path


def read_trace(path) -> list[str]:
    """The lines a tracing probe wrote (empty if it wrote none)."""
    p = Path(path)
    return p.read_text().splitlines() if p.exists() else []


def traced(monkeypatch, tmp_path, name: str = "trace.txt") -> Path:
    """Point $PROBE_TRACE at a fresh file in ``tmp_path`` for this test; returns it."""
    path = Path(tmp_path) / name
    if path.exists():
        path.unlink()
    monkeypatch.setenv("PROBE_TRACE", str(path))
    return path
