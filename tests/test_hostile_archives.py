"""Issue 25 item 1: archives are data, never paths.

Hostile FMU and SSP archives made here with ``zipfile``: an absolute member, a ``../``
member, a symbolic-link member, a zip bomb (a member 1000:1), a central directory that
declares 4 GiB, and a header that under-declares its member. Each must be refused with
an error naming the archive and the member, write nothing outside (the escape target
is checked) and leave nothing behind (the extraction folder and the process's temp
folder are listed before and after).
"""
from __future__ import annotations

import os
import stat
import struct
import tempfile
import zipfile
from pathlib import Path

import pytest

from cosim.fmi import unpack
from cosim.fmi.check import FMUCheckError, safe_extract
from cosim.scenarios.ssp import SSPError, read_ssp

REPO = Path(__file__).resolve().parent.parent
MD = b'<?xml version="1.0"?><fmiModelDescription fmiVersion="2.0" modelName="m" guid="g"/>'
BOMB_BYTES = 20 * 1024 ** 2            # of zeros: deflates about 1000:1


@pytest.fixture
def tmpdir_(tmp_path, monkeypatch):
    """A private temp folder for the FMU extraction folders (listed by the tests)."""
    d = tmp_path / "tmp"
    d.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(d))
    return d


def _zip(path: Path, members: dict, links: dict | None = None) -> Path:
    """A zip of {name: bytes} (deflated) and {name: link target} symbolic links."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)
        for name, target in (links or {}).items():
            info = zipfile.ZipInfo(name)
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
            z.writestr(info, target)
    return path


def _declare(path: Path, member: str, size: int, compressed: int | None = None) -> None:
    """Overwrite the sizes the central directory (and the local header) state for
    ``member``: a header that lies."""
    blob = bytearray(path.read_bytes())
    name = member.encode()
    for sig, off_c, off_u, off_n in ((b"PK\x01\x02", 20, 24, 46), (b"PK\x03\x04", 18, 22, 30)):
        i = blob.find(sig)
        while i >= 0:
            if blob[i + off_n:i + off_n + len(name)] == name:
                if compressed is not None:
                    struct.pack_into("<I", blob, i + off_c, compressed)
                struct.pack_into("<I", blob, i + off_u, size)
            i = blob.find(sig, i + 4)
    path.write_bytes(bytes(blob))


def _hostile(tmp: Path, kind: str) -> tuple[Path, str, str]:
    """(archive, the member at fault, a word the error must hold) of one hostile kind;
    the archive is an FMU (a modelDescription.xml at its root)."""
    f = tmp / f"{kind}.fmu"
    escape = tmp / "escaped" / "evil.pth"
    if kind == "absolute":
        return _zip(f, {"modelDescription.xml": MD, str(escape): b"import os"}), str(escape), "absolute"
    if kind == "dotdot":
        m = "binaries/../../escaped/evil.pth"
        return _zip(f, {"modelDescription.xml": MD, m: b"import os"}), m, ".."
    if kind == "symlink":
        return _zip(f, {"modelDescription.xml": MD}, {"resources/link": str(escape)}), \
            "resources/link", "symbolic link"
    if kind == "bomb":
        return _zip(f, {"modelDescription.xml": MD, "resources/zeros.bin": bytes(BOMB_BYTES)}), \
            "resources/zeros.bin", "ratio"
    if kind == "huge":
        m = "resources/huge.bin"
        _zip(f, {"modelDescription.xml": MD, m: os.urandom(4096)})
        with zipfile.ZipFile(f) as z:       # stored sizes as they are, then 4 GiB declared
            c = z.getinfo(m).compress_size
        _declare(f, m, 0xFFFFFFF0, 0xFFFFFFF0 if c else None)
        return f, "", "2147483648"
    if kind == "lying":                     # declares 1000 bytes, holds 20 MiB
        m = "resources/zeros.bin"
        _zip(f, {"modelDescription.xml": MD, m: bytes(BOMB_BYTES)})
        _declare(f, m, 1000)
        return f, m, "corrupt"
    raise AssertionError(kind)


KINDS = ("absolute", "dotdot", "symlink", "bomb", "huge", "lying")


def test_member_names_are_refused_before_anything_is_written(tmp_path):
    for name, word in (("/etc/x", "absolute"), ("C:/x", "absolute"), ("\\x", "absolute"),
                       ("a/../../x", ".."), ("..\\x", ".."), ("", "empty")):
        with pytest.raises(unpack.UnsafeArchive, match=word):
            unpack.member_parts("a.zip", name)
    assert unpack.member_parts("a.zip", "./a//b\\c.so") == ("a", "b", "c.so")


@pytest.mark.parametrize("kind", KINDS)
def test_hostile_fmu_is_refused_naming_archive_and_member(tmp_path, tmpdir_, kind):
    f, member, word = _hostile(tmp_path, kind)
    before = set(os.listdir(tmpdir_))
    held_before = unpack.held()                     # FMUs other tests still hold
    dest = tmp_path / "dest"
    with pytest.raises(unpack.UnsafeArchive) as e:
        unpack.extract_archive(f, dest)
    msg = str(e.value)
    assert str(f) in msg and member in msg and word in msg, msg
    assert not dest.exists()                        # nothing left behind
    assert not (tmp_path / "escaped").exists()      # nothing written outside
    # the FMU paths: cosim fmus check's extraction, the master's shared extraction
    with pytest.raises(FMUCheckError) as e:
        safe_extract(f, tmp_path / "d2")
    assert str(f) in str(e.value) and member in str(e.value), str(e.value)
    with pytest.raises(FMUCheckError):
        unpack.acquire(f)
    assert set(os.listdir(tmpdir_)) == before       # no cosim-<pid>-* folder, no .part
    assert not (tmp_path / "escaped").exists() and not (tmp_path / "d2").exists()
    assert unpack.held() == held_before             # the refused archive holds nothing


def test_a_bomb_is_refused_from_its_declared_sizes_before_decompressing(tmp_path, monkeypatch):
    """The ratio and size limits act on the central directory: no member is opened."""
    f, _, _ = _hostile(tmp_path, "bomb")
    opened = []
    real = zipfile.ZipFile.open
    monkeypatch.setattr(zipfile.ZipFile, "open", lambda self, *a, **k: opened.append(a) or
                        real(self, *a, **k))
    with pytest.raises(unpack.UnsafeArchive, match="ratio above 100:1"):
        unpack.extract_archive(f, tmp_path / "dest")
    assert opened == []


def test_the_streaming_count_catches_what_the_header_hides(tmp_path):
    """A member whose data holds more than declared, below the declared-size limits:
    the count while writing stops it (here the budget: 1 MiB of zeros, declared 1000
    bytes, limit 64 kB), and the partial folder is removed."""
    f = _zip(tmp_path / "a.zip", {"x.bin": bytes(2 ** 20)})
    _declare(f, "x.bin", 1000)
    with pytest.raises(unpack.UnsafeArchive, match="x.bin") as e:
        unpack.extract_archive(f, tmp_path / "dest", max_bytes=64 * 1024)
    assert "corrupt" in str(e.value) or "declared" in str(e.value)
    assert not (tmp_path / "dest").exists()
    # the same archive honest, within a 64 kB budget: refused by the declared total first
    g = _zip(tmp_path / "b.zip", {"x.bin": os.urandom(40_000), "y.bin": os.urandom(40_000)})
    with pytest.raises(unpack.UnsafeArchive, match="more than 65536 bytes"):
        unpack.extract_archive(g, tmp_path / "dest", max_bytes=64 * 1024)
    assert not (tmp_path / "dest").exists()
    # and within limits it extracts, only under dest
    out = unpack.extract_archive(g, tmp_path / "dest")
    assert sorted(p.name for p in out.iterdir()) == ["x.bin", "y.bin"]


# --------------------------------------------------------------------------- SSP
SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
  version="1.0" name="s"><ssd:System name="s"><ssd:Elements>
  <ssd:Component name="plant" type="application/x-fmu-sharedlibrary" source="{src}"/>
  </ssd:Elements></ssd:System></ssd:SystemStructureDescription>"""


def _ssp(path: Path, src: str, members: dict, links=None) -> Path:
    return _zip(path, {"SystemStructure.ssd": SSD.format(src=src).encode(), **members}, links)


def test_hostile_ssp_archives_are_refused_and_write_nothing(tmp_path):
    escape = tmp_path / "escaped" / "evil.pth"
    fmu = _zip(tmp_path / "ok.fmu", {"modelDescription.xml": MD}).read_bytes()
    cases = {
        "absolute": (_ssp(tmp_path / "abs.ssp", str(escape), {str(escape): b"import os"}),
                     str(escape)),
        "dotdot": (_ssp(tmp_path / "dd.ssp", "resources/../../escaped/evil.pth",
                        {"resources/../../escaped/evil.pth": b"x"}),
                   "resources/../../escaped/evil.pth"),
        "symlink": (_ssp(tmp_path / "ln.ssp", "resources/p.fmu", {"resources/p.fmu": fmu},
                         {"resources/l": str(escape)}), "resources/l"),
        "bomb": (_ssp(tmp_path / "bomb.ssp", "resources/p.fmu",
                      {"resources/p.fmu": bytes(BOMB_BYTES)}), "resources/p.fmu"),
    }
    for kind, (f, member) in cases.items():
        dest = tmp_path / "cache" / kind
        with pytest.raises(SSPError) as e:
            read_ssp(f, dest)
        assert str(f) in str(e.value) and member in str(e.value), (kind, str(e.value))
        assert not escape.exists() and not escape.parent.exists(), kind
        assert not dest.exists(), kind
        assert not (tmp_path / "cache").exists() or not list((tmp_path / "cache").iterdir()), kind
    # the .ssd itself as a bomb: held to its size limit, not read whole
    f = _zip(tmp_path / "ssd.ssp", {"SystemStructure.ssd": b" " * (70 * 1024 ** 2)})
    with pytest.raises(SSPError, match="SystemStructure.ssd"):
        read_ssp(f, tmp_path / "cache" / "ssd")


def test_ssp_fmus_go_to_private_folders_and_a_tampered_copy_is_replaced(tmp_path):
    fmu = _zip(tmp_path / "ok.fmu", {"modelDescription.xml": MD}).read_bytes()
    f = _ssp(tmp_path / "a.ssp", "resources/sub/p.fmu", {"resources/sub/p.fmu": fmu})
    dest = tmp_path / "cache" / "a"
    got = Path(read_ssp(f, dest)["fmus"]["plant"]["fmu"])
    assert got.parent.parent == dest and got.name == "p.fmu" and got.read_bytes() == fmu
    got.write_bytes(b"tampered")                    # the cache is checked when reused
    again = Path(read_ssp(f, dest)["fmus"]["plant"]["fmu"])
    assert again.read_bytes() == fmu
    assert sorted(p.name for p in dest.parent.iterdir()) == ["a"]    # no .part left


def test_cache_is_per_user_and_version_and_printed_by_version(tmp_path, monkeypatch, capsys):
    import cosim
    from cosim.cli import main
    monkeypatch.delenv("COSIM_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and out.startswith("cosim ")
    assert f" {cosim.__version__} " in out.splitlines()[0]
    assert str(tmp_path / "xdg" / "rehab-cosim" / cosim.__version__) in out


def test_a_member_listed_twice_with_the_same_bytes_is_extracted_once(tmp_path):
    """Reference-FMUs' Roberts lists its extra/ files twice, byte for byte: that archive
    unpacks; a second member of the same name with other bytes is refused, naming it."""
    import warnings
    same = tmp_path / "same.zip"
    other = tmp_path / "other.zip"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)      # zipfile: "Duplicate name"
        with zipfile.ZipFile(same, "w") as z:
            z.writestr("extra/m.xml", b"<m/>")
            z.writestr("extra/m.xml", b"<m/>")
            z.writestr("a.txt", b"a")
        with zipfile.ZipFile(other, "w") as z:
            z.writestr("extra/m.xml", b"<m/>")
            z.writestr("extra/m.xml", b"<evil/>")
    dest = unpack.extract_archive(same, tmp_path / "d1")
    assert (dest / "extra" / "m.xml").read_bytes() == b"<m/>"
    assert (dest / "a.txt").read_bytes() == b"a"
    with pytest.raises(unpack.UnsafeArchive, match="other content") as e:
        unpack.extract_archive(other, tmp_path / "d2")
    assert "extra/m.xml" in str(e.value) and not (tmp_path / "d2").exists()
