"""Input files the probes write: a user's own files (PNG, GIF, HTML, ...), TOML text, model files."""

from __future__ import annotations

import hashlib
import math
import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any


def png_bytes() -> bytes:
    """A valid 2x2 grey PNG, as a user's own picture (no shinro-ctrl marker)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    raw = b"".join(b"\x00" + b"\x80\x80" for _ in range(2))
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 2, 8, 0, 0, 0, 0))
        + chunk(b"tEXt", b"Author\x00my holiday photo")
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )


GIF = (
    b"GIF89a\x01\x00\x01\x00\x80\x00\x00\x00\x00\x00\xff\xff\xff!\xf9\x04\x01\x00\x00\x00\x00"
    b",\x00\x00\x00\x00\x01\x00\x01\x00\x00\x02\x02D\x01\x00;"
)
USER_FILES: dict[str, bytes] = {
    "png": png_bytes(),
    "gif": GIF,
    "html": b"<!DOCTYPE html>\n<html><head><title>my thesis notes</title></head><body>mine</body></html>\n",
    "csv": b"a,b\n1,2\n",
    "json": b'{"mine": true, "metrics": {"rms_error": 1.0}}\n',
    "npz": b"PK\x05\x06" + b"\x00" * 18,  # an empty zip archive, as numpy writes one
    "toml": b'# my notes\n[plant]\ntype = "CartPole"\n',
    "pdf": b"%PDF-1.4\n% my paper\n%%EOF\n",
    "mp4": b"\x00\x00\x00\x18ftypmp42\x00\x00\x00\x00mp42isom",
    "txt": b"my shopping list\n",
}


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def user_file(
    name: str, kind: str, *, link: bool = False
) -> tuple[Callable[[Path], None], Callable[[Path], str | None]]:
    """Setup and data-loss check for a user's own file at ``name`` (through a symlink when ``link``)."""
    data = USER_FILES[kind]

    def setup(wd: Path) -> None:
        target = wd / ("mine/" + Path(name).name if link else name)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
        if link:
            (wd / name).parent.mkdir(parents=True, exist_ok=True)
            (wd / name).symlink_to(target)

    def check(wd: Path) -> str | None:
        target = wd / ("mine/" + Path(name).name if link else name)
        if not target.exists():
            return f"the user's {kind.upper()} {name} was deleted"
        if target.read_bytes() != data:
            return f"the user's {kind.upper()} {name}{' (through a symlink)' if link else ''} was overwritten"
        return None

    return setup, check


def user_folder(name: str, files: dict[str, bytes]) -> tuple[Callable[[Path], None], Callable[[Path], str | None]]:
    """A user's folder holding ``files``: every one must be byte-identical afterwards."""

    def setup(wd: Path) -> None:
        (wd / name).mkdir(parents=True, exist_ok=True)
        for fname, data in files.items():
            (wd / name / fname).write_bytes(data)

    def check(wd: Path) -> str | None:
        for fname, data in files.items():
            p = wd / name / fname
            if not p.exists():
                return f"the user's {name}/{fname} was deleted"
            if p.read_bytes() != data:
                return f"the user's {name}/{fname} was overwritten"
        return None

    return setup, check


def write_text(name: str, text: str | bytes) -> Callable[[Path], None]:
    def setup(wd: Path) -> None:
        p = wd / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            p.write_bytes(text)
        else:
            p.write_text(text)

    return setup


def chain(*setups: Callable[[Path], None] | None) -> Callable[[Path], None]:
    def setup(wd: Path) -> None:
        for s in setups:
            if s is not None:
                s(wd)

    return setup


# ------------------------------------------------------------------ TOML writing
class Raw(str):
    """A TOML value written verbatim (e.g. a deliberately broken token)."""


def toml_value(v: Any) -> str:
    if isinstance(v, Raw):
        return str(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else toml_value(k)


def dump_toml(doc: dict[str, Any]) -> str:
    """Top-level tables as ``[name]`` sections, everything else inline."""
    lines: list[str] = []
    for k, v in doc.items():
        if not isinstance(v, dict):
            lines.append(f"{_key(k)} = {toml_value(v)}")
    for k, v in doc.items():
        if isinstance(v, dict):
            lines.append(f"\n[{_key(k)}]")
            for kk, vv in v.items():
                lines.append(f"{_key(kk)} = {toml_value(vv)}")
    return "\n".join(lines) + "\n"
