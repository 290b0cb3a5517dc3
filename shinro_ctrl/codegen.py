"""Compiled CasADi functions: C code generation, built once with the system compiler and cached on disk.

:func:`compiled` takes a CasADi :class:`casadi.Function`, generates its C
code, compiles it into a shared library with the system C compiler (``$CC``,
else ``cc`` or ``gcc``) and returns the library loaded as an external
function: same inputs, outputs and names, evaluated as machine code instead
of the CasADi virtual machine.

The library is cached on disk under a key made of the generated source, the
compiler and its flags (a SHA-256), so the second process that asks for the
same expression loads it in milliseconds instead of compiling again, and a
changed expression can never load a stale library. The cache folder is
``$SHINRO_CTRL_CACHE``, else ``$XDG_CACHE_HOME/shinro_ctrl``, else
``~/.cache/shinro_ctrl`` (subfolder ``codegen``); libraries are written under
a temporary name and renamed into place, so no process ever loads a
half-written file, and under a lock file per library, so concurrent processes
asking for the same function compile it once (the others wait and load it).

:func:`compiled_by_key` is the same for an expression that is expensive to
build: the caller names what it depends on (a robot's numbers and the source
of the code that builds it), so a cache hit skips building it altogether.

Nothing is compiled at import. Without a working compiler (none found, or the
build fails) :func:`compiled` returns the function unchanged and warns once
per reason with a one-line :class:`CompilerUnavailable` note: the results are
the same, only slower.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shlex
import shutil
import subprocess
import tempfile
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import casadi as cs

__all__ = [
    "DEFAULT_FLAGS",
    "CompilerUnavailable",
    "cache_dir",
    "compiled",
    "compiled_by_key",
    "default_flags",
    "find_compiler",
]

#: Default optimization flags: ``-O1`` compiles large generated Jacobians several times faster than ``-O3`` and runs
#: them about as fast (the generated code is straight-line arithmetic with little left to optimize).
DEFAULT_FLAGS: tuple[str, ...] = ("-O1",)


def default_flags() -> tuple[str, ...]:
    """``$SHINRO_CTRL_CFLAGS`` split like a shell would (e.g. ``"-O2 -march=native"``), else :data:`DEFAULT_FLAGS`.

    The flags are part of every cache key, so libraries built with other flags are never mixed up. The test suite
    sets ``-O0`` (a quarter of the compile time, the same arithmetic: no fast-math, no FMA contraction on the default
    target), since it compiles every model it loads once and calls each only a few times.
    """
    env = os.environ.get("SHINRO_CTRL_CFLAGS", "").strip()
    return tuple(shlex.split(env)) if env else DEFAULT_FLAGS


_lock = threading.Lock()
_warned: set[str] = set()


class CompilerUnavailable(UserWarning):
    """No C compiler could build a generated function; the CasADi virtual machine evaluates it instead (slower)."""


def find_compiler() -> str | None:
    """The C compiler to use: ``$CC`` when set, else ``cc`` or ``gcc`` on the ``PATH``; None when there is none."""
    env = os.environ.get("CC", "").strip()
    if env:
        return shutil.which(env.split()[0]) and env
    for name in ("cc", "gcc"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _no_compiler() -> str:
    env = os.environ.get("CC", "").strip()
    if env:
        return f"no C compiler: CC={env!r} is not a program on the PATH"
    return "no C compiler found (set CC or install gcc)"


def cache_dir() -> Path:
    """The folder compiled libraries are cached in (created on first use)."""
    root = os.environ.get("SHINRO_CTRL_CACHE")
    if root:
        base = Path(root)
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = (Path(xdg) if xdg else Path.home() / ".cache") / "shinro_ctrl"
    return base / "codegen"


def _note(reason: str) -> None:
    with _lock:
        if reason in _warned:
            return
        _warned.add(reason)
    warnings.warn(
        f"{reason}; evaluating with CasADi's virtual machine (same results, slower)", CompilerUnavailable, stacklevel=3
    )


def _source(fun: cs.Function) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        name = f"{fun.name()}.c"
        gen = cs.CodeGenerator(name, {"with_header": False, "casadi_real": "double", "casadi_int": "long long int"})
        gen.add(fun)
        gen.generate(tmp + os.sep)
        return (Path(tmp) / name).read_text()


def _link(name: str, digest: str, src: Callable[[], str], flags: Sequence[str], folder: Path | None) -> Path | None:
    """The library ``<folder>/<name>_<digest>.so``, compiled from ``src()`` unless already cached; None on failure."""
    cc = find_compiler()
    if cc is None:
        _note(_no_compiler())
        return None
    folder = cache_dir() if folder is None else Path(folder)
    lib = folder / f"{name}_{digest}.so"
    if lib.is_file():
        return lib
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _note(f"cache folder {folder} is not writable ({exc.strerror})")
        return None
    with _file_lock(folder / f"{lib.name}.lock"):  # another process building the same key: wait, then load its
        if lib.is_file():
            return lib
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            c_file = Path(tmp) / f"{name}.c"
            c_file.write_text(src())
            out = Path(tmp) / lib.name
            cmd = [*cc.split(), *flags, "-shared", "-fPIC", "-o", str(out), str(c_file), "-lm"]
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                first = (proc.stderr.strip().splitlines() or ["no output"])[0]
                _note(f"{Path(cc.split()[0]).name} could not build {name} ({first})")
                return None
            os.replace(out, lib)  # atomic: no process ever loads a half-written library
    return lib


@contextlib.contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    """An exclusive advisory lock on ``path`` across processes (``fcntl``; none where it does not exist)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: the atomic rename alone keeps builds safe
        yield
        return
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _digest(*parts: str) -> str:
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()[:24]


def compiled(fun: cs.Function, *, flags: Sequence[str] | None = None, folder: Path | None = None) -> cs.Function:
    """``fun`` as compiled machine code, built once and cached on disk.

    Args:
        fun: Any CasADi function that supports code generation (``SX``
            functions and ``MX`` functions of such); its name becomes the C
            symbol, so give distinct functions distinct names.
        flags: Compiler flags besides ``-shared -fPIC`` (part of the cache key); default :func:`default_flags`.
        folder: The cache folder; default :func:`cache_dir`.

    Returns:
        A function with ``fun``'s signature backed by the compiled library, or
        ``fun`` itself (with a one-line :class:`CompilerUnavailable` warning)
        when no compiler can build it.
    """
    cc = find_compiler()
    if cc is None:
        _note(_no_compiler())
        return fun
    flags = default_flags() if flags is None else tuple(flags)
    src = _source(fun)
    lib = _link(fun.name(), _digest(src, cc, *flags), lambda: src, flags, folder)
    return fun if lib is None else cs.external(fun.name(), str(lib))


def compiled_by_key(
    name: str,
    key: str,
    build: Callable[[], cs.Function],
    *,
    flags: Sequence[str] | None = None,
    folder: Path | None = None,
) -> cs.Function:
    """A compiled function found by a key the caller computes, built (by ``build()``) only when not cached.

    :func:`compiled` must build the expression and generate its C source to
    find its cache key; when the expression is expensive to build (a robot's
    exact Jacobians take ~0.3 s) but determined by cheaper data (the model's
    numbers and the source of the code that builds it), key on those instead:
    a cache hit then costs one ``dlopen``.

    Args:
        name: The function's name (``build()`` must return a function of that name).
        key: Everything the expression depends on, as text (hashed together
            with the compiler, its flags and the CasADi version). A key that
            misses an input can load a stale library: include the source of
            the code that builds the expression.
        build: Returns the CasADi function; called on a cache miss, and when no
            compiler can build it (the virtual-machine fallback).
        flags: Compiler flags besides ``-shared -fPIC``; default :func:`default_flags`.
        folder: The cache folder; default :func:`cache_dir`.

    Returns:
        The compiled function, or ``build()`` itself with a one-line
        :class:`CompilerUnavailable` warning when no compiler can build it.
    """
    built: list[cs.Function] = []

    def source() -> str:
        built.append(build())
        if built[0].name() != name:
            raise ValueError(f"build() returned a function named {built[0].name()!r}, expected {name!r}")
        return _source(built[0])

    cc = find_compiler() or ""
    flags = default_flags() if flags is None else tuple(flags)
    lib = _link(name, _digest(key, cc, *flags, cs.__version__), source, flags, folder)
    if lib is None:
        return built[0] if built else build()
    return cs.external(name, str(lib))
