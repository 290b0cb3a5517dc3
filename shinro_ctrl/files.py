"""Safe file output: atomic files, atomic folders of files, stale-temp cleanup, and output-path checks.

Every file the workbench writes goes through :func:`atomic_write` (a temporary
file beside the target, fsynced, renamed over it), so a kill leaves the old
file or the new one. A *set* of files that belong together (a run's
``result.npz``, ``metrics.json``, ``scenario.toml`` and plot) is written with
:func:`atomic_folder`: into a fresh hidden folder that is swapped with the
target in one ``rename``, so a folder always holds one complete run or the
previous one.

Temporary files and folders carry an advisory lock (``flock``) for as long as
their writer lives; :func:`remove_stale_temps` deletes only those whose lock
it can take (their writer died), never another live writer's.

Nothing a user owns is overwritten. Every file the workbench writes for a
user carries the marker :data:`GENERATOR` inside it (a PNG ``tEXt`` chunk
``Software``, a GIF comment, an HTML ``<meta name="generator">``, PDF
``Creator``/``Producer`` metadata, an SVG ``<dc:creator>``, an NPZ member, an MP4 comment) and every
folder it writes carries the manifest :data:`RUN_MANIFEST` (which covers the
folder's CSV, JSON and NPZ files). :func:`check_output_file`,
:func:`check_output_folder` and :func:`write_output` replace an existing file
or folder only when it carries the marker, never follow a symbolic link to
replace its target, and refuse one of the command's input files: each with
one line, before any work is done.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import json
import os
import re
import shutil
import struct
import tempfile
import zipfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from shinro_ctrl._text_formats import dump_toml, json_safe
from shinro_ctrl.errors import InvalidArgument

try:  # POSIX advisory locks; without them (Windows) nothing counts as provably stale
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "GENERATOR",
    "NPZ_MARKER",
    "RUN_MANIFEST",
    "atomic_folder",
    "atomic_write",
    "atomic_write_set",
    "check_not_input",
    "check_output_file",
    "check_output_folder",
    "check_replaceable",
    "dump_json",
    "dump_toml",
    "is_device",
    "recover_journals",
    "remove_stale_temps",
    "write_output",
    "written_by_us",
]

RUN_MANIFEST = ".shinro-run.json"  # written last into a run folder: the names (and sizes) of its files
TEMP_SUFFIX = ".tmp"
GENERATOR = "shinro-ctrl"  # the marker inside every file we write (see the module docstring)
NPZ_MARKER = "generator"  # the member of our .npz files that holds GENERATOR
HTML_MARKER = f'<meta name="generator" content="{GENERATOR}">'


# ---------------------------------------------------------------- locks
def _try_lock(fd: int) -> bool:
    """Take an exclusive, non-blocking advisory lock on ``fd``; False if another process holds it."""
    if fcntl is None:  # pragma: no cover
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def _same_inode(fd: int, path: str | Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path, follow_symlinks=False)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _locked_tempfile(directory: Path, prefix: str) -> tuple[int, str]:
    """``mkstemp`` whose file is locked by this process (retried if a cleaner got it first)."""
    for _ in range(100):
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=TEMP_SUFFIX, dir=directory)
        if (fcntl is None or _try_lock(fd)) and _same_inode(fd, tmp):
            return fd, tmp
        os.close(fd)
    raise OSError(errno.EAGAIN, f"could not create a temporary file in '{directory}'")


def remove_stale_temps(directory: str | Path, pattern: str = f".*{TEMP_SUFFIX}") -> list[Path]:
    """Delete temporary files and folders in ``directory`` whose writer is gone.

    A temporary (see :func:`atomic_write`, :func:`atomic_folder`) is stale when
    its advisory lock can be taken: the process that created it holds the lock
    until it finishes, so a live writer's file (another ``regress --update`` on
    the same folder) is never touched.

    Returns:
        The paths removed.
    """
    removed = []
    for path in Path(directory).glob(pattern):
        try:
            fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
        except OSError:
            continue
        try:
            if not _try_lock(fd) or not _same_inode(fd, path):
                continue
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
            removed.append(path)
        finally:
            os.close(fd)
    return removed


# --------------------------------------------------------------- single files
def _target(path: Path) -> Path:
    """The file a write must replace: the final target of a symlink (its link stays a link)."""
    if path.is_symlink():
        return Path(os.path.realpath(path))
    return path


def atomic_write(path: str | Path, write: Callable[[Any], None], *, binary: bool = False) -> Path:
    """Write a file atomically: ``write(f)`` fills a temporary file that then replaces ``path``.

    An interrupted run leaves either the old file or the new one, never a
    half-written one; the temporary is locked while it is written and removed
    on any error. A symlink is written through (its target is replaced, the
    link stays). Errors name ``path``, never the temporary.

    Returns:
        ``path`` as given.
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        if path.is_dir():
            raise IsADirectoryError(errno.EISDIR, "is a directory, not a file", str(path))
        # A device or pipe (/dev/null, /dev/stdout): renaming over it would replace the device itself.
        with open(path, "wb" if binary else "w", encoding=None if binary else "utf-8") as f:
            write(f)
        return path
    target = _target(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _locked_tempfile(target.parent, f".{target.name}.")
    except OSError as exc:
        raise _named(exc, path) from None
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the file the permissions open() would
        with os.fdopen(os.dup(fd), "wb" if binary else "w", encoding=None if binary else "utf-8") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise _named(exc, path) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        os.close(fd)
    return path


def _named(exc: OSError, path: Path) -> OSError:
    """The same error, naming the user's path instead of a temporary."""
    if exc.errno:
        return type(exc)(exc.errno, exc.strerror or os.strerror(exc.errno), str(path))
    return OSError(f"cannot write '{path}': {exc}")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# ------------------------------------------------------------- sets of files
JOURNAL_PATTERN = ".shinro-journal.*.json"


def atomic_write_set(files: Mapping[str | Path, str], journal_dir: str | Path) -> list[Path]:
    """Replace several text files as one set: all new or all old, even if killed.

    Every new file is written and fsynced to a locked temporary beside its
    target first (an error there leaves every target untouched); then a
    journal listing the renames is committed in ``journal_dir``, the renames
    run and the journal is removed. A kill during the renames leaves the
    journal, which :func:`recover_journals` (called by the next writer or
    reader of the folder) completes. Symlinks are written through.

    Returns:
        The paths written, as given.
    """
    journal_dir = Path(journal_dir)
    for path in files:  # everything that can be checked is checked before the first byte is written
        target = _target(Path(path))
        if target.is_dir():
            raise IsADirectoryError(errno.EISDIR, "is a directory, not a file", str(path))
    temps: list[tuple[int, str, Path]] = []
    jfd = -1
    try:
        for path, text in files.items():
            target = _target(Path(path))
            try:
                fd, tmp = _locked_tempfile(target.parent, f".{target.name}.")
            except OSError as exc:
                raise _named(exc, Path(path)) from None
            temps.append((fd, tmp, target))
            os.chmod(tmp, 0o666 & ~_umask())
            with os.fdopen(os.dup(fd), "w", encoding="utf-8") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
        moves = [[tmp, str(target)] for _, tmp, target in temps]
        jfd, jtmp = _locked_tempfile(journal_dir, ".shinro-journal.")
        with os.fdopen(os.dup(jfd), "w", encoding="utf-8") as f:
            f.write(json.dumps({"moves": moves}) + "\n")
            f.flush()
            os.fsync(f.fileno())
        journal = journal_dir / (Path(jtmp).name.removesuffix(TEMP_SUFFIX) + ".json")
        os.replace(jtmp, journal)  # the commit point
        _fsync_dir(journal_dir)
    except BaseException:
        for _, tmp, _ in temps:
            Path(tmp).unlink(missing_ok=True)
        if jfd >= 0:
            Path(jtmp).unlink(missing_ok=True)
        for fd, _, _ in temps:
            os.close(fd)
        if jfd >= 0:
            os.close(jfd)
        raise
    try:
        for _, tmp, target in temps:
            os.replace(tmp, target)
        for d in {target.parent for _, _, target in temps}:
            _fsync_dir(d)
        journal.unlink()
    finally:
        for fd, _, _ in temps:
            os.close(fd)
        os.close(jfd)
    return [Path(p) for p in files]


def recover_journals(directory: str | Path) -> int:
    """Complete the renames of :func:`atomic_write_set` calls that were killed after their commit point.

    A journal still locked belongs to a live writer and is left alone.

    Returns:
        The number of journals completed.
    """
    done = 0
    for journal in sorted(Path(directory).glob(JOURNAL_PATTERN)):
        try:
            fd = os.open(journal, os.O_RDONLY)
        except OSError:
            continue
        try:
            if not _try_lock(fd) or not _same_inode(fd, journal):
                continue
            try:
                moves = json.loads(journal.read_text(encoding="utf-8"))["moves"]
            except (ValueError, KeyError, TypeError):
                continue
            for tmp, target in moves:
                if Path(tmp).exists():
                    try:
                        os.replace(tmp, target)
                    except OSError:  # a target that became a folder: its temporary is cleaned up as stale
                        continue
            journal.unlink(missing_ok=True)
            done += 1
        finally:
            os.close(fd)
    return done


# ------------------------------------------------------------------- folders
_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where unsupported."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd = -100
    rc = renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


@contextlib.contextmanager
def atomic_folder(directory: str | Path, names: Iterable[str] = ()) -> Iterator[Path]:
    """Build a folder's files in a fresh hidden folder and swap it into place in one step.

    ``with atomic_folder(out, RUN_FILES) as tmp:`` — write every file into
    ``tmp``; on leaving the block the manifest :data:`RUN_MANIFEST` is written
    last and ``tmp`` replaces ``directory`` atomically (the previous contents
    are removed). An exception or a kill inside the block leaves ``directory``
    as it was; the orphaned temporary folder is removed by the next call.

    Only a new or empty folder, or one shinro-ctrl wrote (it holds the
    manifest), is replaced; a symbolic link is never followed.

    Args:
        directory: The output folder (created).
        names: The files the block may write (checked by :func:`check_output_folder` beforehand).

    Raises:
        InvalidArgument: ``directory`` is a symbolic link, not a folder, or a folder shinro-ctrl did not write.
    """
    directory = Path(directory)
    _check_folder_replaceable(directory)
    target = Path(os.path.abspath(directory))
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(parent, f".{target.name}.*{TEMP_SUFFIX}")
        for _ in range(100):
            tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=TEMP_SUFFIX, dir=parent))
            lock = os.open(tmp, os.O_RDONLY)
            if _try_lock(lock) and _same_inode(lock, tmp):
                break
            os.close(lock)
        else:  # pragma: no cover
            raise OSError(errno.EAGAIN, "could not create a temporary folder", str(parent))
    except OSError as exc:
        raise _named(exc, directory) from None
    try:
        os.chmod(tmp, 0o777 & ~_umask())
        yield tmp
        written = sorted(p.name for p in tmp.iterdir() if not p.name.startswith("."))
        manifest = {"files": {n: (tmp / n).stat().st_size for n in written}, "expected": sorted(names)}
        atomic_write(tmp / RUN_MANIFEST, lambda f: f.write(json.dumps(manifest, indent=1) + "\n"))
        _fsync_dir(tmp)
        if target.exists() and not target.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "exists and is not a folder", str(directory))
        if not target.exists():
            os.rename(tmp, target)
        elif not _exchange(tmp, target):  # pragma: no cover - non-Linux: two renames, a short window
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=TEMP_SUFFIX, dir=parent))
            os.rename(target, old / "previous")
            os.rename(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
        _fsync_dir(parent)
    except OSError as exc:
        raise _named(exc, directory) from None
    finally:
        os.close(lock)
        shutil.rmtree(tmp, ignore_errors=True)  # the previous contents after the swap, or the aborted build


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# ------------------------------------------------------------ our marker
_MARK = GENERATOR.encode()
_SCAN_LIMIT = 256 * 2**20  # bytes of an MP4/PDF scanned for the marker


def _png_marked(f: Any) -> bool:
    """A ``tEXt``/``iTXt`` chunk ``Software`` = :data:`GENERATOR` (chunks walked by their lengths)."""
    f.seek(8)
    while True:
        head = f.read(8)
        if len(head) < 8:
            return False
        length, ctype = struct.unpack(">I4s", head)
        if ctype == b"IEND":
            return False
        if ctype in (b"tEXt", b"iTXt") and length < 2**16:
            key, _, value = f.read(length).partition(b"\0")
            if ctype == b"iTXt":  # compression flag, method, language\0, translated keyword\0, text
                value = value[2:].split(b"\0", 2)[-1] if value[:1] == b"\0" else b""
            if key == b"Software" and value == _MARK:
                return True
            f.seek(4, os.SEEK_CUR)
        else:
            f.seek(length + 4, os.SEEK_CUR)


#: The creator matplotlib writes into an SVG's ``<metadata>`` for ``metadata={"Creator": GENERATOR}``.
_SVG_MARK = re.compile(rb"<dc:creator>\s*<cc:Agent>\s*<dc:title>" + re.escape(_MARK) + rb"</dc:title>")


def _svg_marked(f: Any) -> bool:
    """An SVG whose ``<metadata>`` names :data:`GENERATOR` as its creator (matplotlib writes it near the top)."""
    head = f.read(2**16)
    return b"<svg" in head and _SVG_MARK.search(head) is not None


def _gif_marked(f: Any) -> bool:
    """A comment extension holding exactly :data:`GENERATOR` (Pillow writes it before the first frame)."""
    return b"\x21\xfe" + bytes([len(_MARK)]) + _MARK + b"\0" in f.read(2**20)


def _contains(f: Any, needle: bytes) -> bool:
    """``needle`` anywhere in the first :data:`_SCAN_LIMIT` bytes (read in blocks)."""
    tail, read = b"", 0
    while read < _SCAN_LIMIT:
        block = f.read(2**20)
        if not block:
            return False
        if needle in tail + block:
            return True
        tail, read = block[-len(needle) :], read + len(block)
    return False


def _npz_marked(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            if f"{NPZ_MARKER}.npy" not in z.namelist():
                return False
            import numpy as np

            with z.open(f"{NPZ_MARKER}.npy") as member:
                value = np.lib.format.read_array(member, allow_pickle=False)
            return value.shape == () and str(value) == GENERATOR
    except (zipfile.BadZipFile, OSError, ValueError, KeyError, EOFError):
        return False


def written_by_us(path: str | Path) -> bool:
    """Whether the regular file ``path`` carries our marker (judged by its content, whatever its name).

    PNG: a ``tEXt`` chunk ``Software=shinro-ctrl``; GIF: that comment; PDF:
    ``/Creator (shinro-ctrl)``; SVG: ``<dc:creator>`` holding it in its ``<metadata>``;
    HTML: ``<meta name="generator" content="shinro-ctrl">`` in its head;
    NPZ: a member ``generator`` holding it; MP4: a ``comment``
    tag holding it. Anything else (an empty file too) is not ours.
    """
    p = Path(path)
    try:
        with open(p, "rb") as f:
            head = f.read(16)
            f.seek(0)
            if head.startswith(b"\x89PNG\r\n\x1a\n"):
                return _png_marked(f)
            if head.startswith(b"GIF8"):
                return _gif_marked(f)
            if head.startswith(b"%PDF"):
                return _contains(f, b"/Creator (" + _MARK + b")")
            if head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith((b"<?xml", b"<svg")):
                return _svg_marked(f) or HTML_MARKER.encode() in f.read(4096).lower()
            if head[4:8] == b"ftyp":
                return _contains(f, _MARK)
            if head.startswith(b"PK\x03\x04"):
                return _npz_marked(p)
            return HTML_MARKER.encode() in f.read(4096).lower()
    except OSError:
        return False


# ------------------------------------------------------------- output checks
def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def is_device(path: str | Path) -> bool:
    """A character device, pipe or socket (``/dev/null``, ``/dev/stdout``): written through, never renamed over."""
    p = Path(path)
    try:
        return p.exists() and not p.is_file() and not p.is_dir()
    except OSError:
        return False


_is_device = is_device


def _kind_name(p: Path, kind: str | None) -> str:
    """``"a PNG file"``, ``"an HTML report"``: what ``p`` should be, for a message."""
    kind = kind or p.suffix
    if not kind:
        return "a file"
    if " " not in kind:
        kind = f"{kind.lstrip('.').upper()} file"
    return f"{'an' if kind[:1] in 'AEFHILMNORSX' else 'a'} {kind}"


def check_replaceable(path: str | Path, *, what: str = "output", kind: str | None = None) -> Path:
    """Refuse to replace ``path`` unless it is new, a device, or a file shinro-ctrl wrote.

    Refused: a symbolic link (its target is never replaced through it; a link
    to a device is written through), a folder, and an existing file that does
    not carry our marker (:func:`written_by_us`), such as the user's own photo
    given as ``--plot``.

    Args:
        path: The output file.
        what: The option or role named in the message (``"--plot"``).
        kind: What the file should be, for the message (``"PNG"``, ``"HTML report"``; default: by the suffix).

    Raises:
        InvalidArgument: naming ``what``, the path and the reason.
    """
    p = Path(path)
    if _is_device(p):
        return p
    if p.is_symlink():
        raise InvalidArgument(
            f"{what} '{p}' is a symbolic link (to '{os.readlink(p)}'); refusing to replace a file through a link "
            "(give the real path or another name)"
        )
    if p.is_dir():
        raise InvalidArgument(f"{what} '{p}' is a folder; give a file name")
    if p.exists() and not written_by_us(p):
        raise InvalidArgument(
            f"{what} '{p}' exists and is not {_kind_name(p, kind)} written by {GENERATOR}; refusing to overwrite it "
            "(remove it or choose another name)"
        )
    return p


def write_output(
    path: str | Path,
    write: Callable[[Any], None],
    *,
    binary: bool = False,
    what: str = "output",
    kind: str | None = None,
) -> Path:
    """:func:`atomic_write` for a user-facing output: only over a new file, a device or one of ours.

    The writer ``write(f)`` must put our marker into the file (see
    :func:`written_by_us`) so that the next run may replace it.

    Raises:
        InvalidArgument: see :func:`check_replaceable`.
    """
    check_replaceable(path, what=what, kind=kind)
    return atomic_write(path, write, binary=binary)


def check_not_input(path: str | Path, inputs: Iterable[str | Path | None], *, what: str = "output") -> None:
    """Refuse an output ``path`` that is one of the command's ``inputs`` (also through a link or ``..``).

    Raises:
        InvalidArgument: naming ``what``, the path and the input.
    """
    p = Path(path)
    for inp in inputs:
        if inp is not None and _same_file(p, Path(inp)):
            raise InvalidArgument(f"{what} '{p}' is the input file '{inp}': an output never overwrites an input")


def check_output_file(
    path: str | Path, *, inputs: Iterable[str | Path] = (), what: str = "output", kind: str | None = None
) -> Path:
    """Refuse, before any work, an output path that would destroy something the user owns.

    Refused: one of the command's ``inputs`` (also through a link), and what
    :func:`check_replaceable` refuses: a symbolic link, a folder, an existing
    file shinro-ctrl did not write (judged by the marker inside it, never by
    its name or magic bytes), and a path whose folder cannot be written.
    ``kind`` names what the file should be in the message (``"PNG"``).

    Raises:
        InvalidArgument: naming the path and the reason.
    """
    p = Path(path)
    check_not_input(p, inputs, what=what)
    check_replaceable(p, what=what, kind=kind)
    if _is_device(p):
        return p  # a device or pipe: written through
    _check_writable_parent(p, what)
    return p


def _folder_is_ours(d: Path) -> bool:
    """An empty folder, or one holding our manifest (valid JSON with the written file names)."""
    entries = list(d.iterdir())
    if not entries:
        return True
    try:
        manifest = json.loads((d / RUN_MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(manifest, dict) and isinstance(manifest.get("files"), dict)


def _check_folder_replaceable(d: Path, what: str = "output folder") -> None:
    if d.is_symlink():
        raise InvalidArgument(
            f"{what} '{d}' is a symbolic link (to '{os.readlink(d)}'); refusing to replace a folder through a link "
            "(give the real path or another name)"
        )
    if d.exists() and not d.is_dir():
        raise InvalidArgument(f"{what} '{d}' exists and is not a folder")
    if d.is_dir() and not _folder_is_ours(d):
        raise InvalidArgument(
            f"{what} '{d}' holds files but is not a run output of {GENERATOR} (it has no manifest {RUN_MANIFEST}); "
            "it is replaced as a whole, so choose a new or empty folder"
        )


def check_output_folder(
    directory: str | Path, names: Iterable[str], *, inputs: Iterable[str | Path] = (), what: str = "output folder"
) -> Path:
    """Refuse, before any work, an output folder whose contents are not an earlier output.

    The folder may be new, empty, or one shinro-ctrl wrote (it holds the
    manifest :data:`RUN_MANIFEST`) holding only files named in ``names``: it
    is replaced as a whole by :func:`atomic_folder`, so a folder holding
    anything else (the input scenario, the user's own ``metrics.json``) or a
    symbolic link is refused rather than lost.

    Args:
        directory: The output folder.
        names: The files the command writes into it.
        inputs: The command's input files, never overwritten.
        what: How the message names the folder, with its option (``"--out folder"``).

    Raises:
        InvalidArgument: naming ``what``, the folder and the reason.
    """
    d = Path(directory)
    allowed = {*names, RUN_MANIFEST}
    if d.is_dir() and not d.is_symlink():
        for inp in inputs:
            if inp is not None and any(_same_file(e, Path(inp)) for e in d.iterdir()):
                raise InvalidArgument(
                    f"{what} '{d}' holds the input file '{inp}': an output never overwrites an input; "
                    "choose another folder"
                )
    _check_folder_replaceable(d, what)
    if d.is_dir():
        foreign = sorted(e.name for e in d.iterdir() if e.name not in allowed)
        if foreign:
            raise InvalidArgument(
                f"{what} '{d}' holds '{foreign[0]}'"
                + (f" and {len(foreign) - 1} more entries" if len(foreign) > 1 else "")
                + f", which is not a run output ({', '.join(sorted(names))}); it is replaced as a whole, "
                "so choose a new or empty folder"
            )
    _check_writable_parent(d, what)
    return d


def _check_writable_parent(p: Path, what: str) -> None:
    parent = p.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InvalidArgument(f"{what} '{p}': '{parent}' is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InvalidArgument(f"{what} '{p}': no permission to write in '{parent}'")


# ---------------------------------------------------------------- formats
def dump_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented JSON atomically (infinities as the strings ``"inf"``)."""
    text = json.dumps(json_safe(data), indent=2, sort_keys=True) + "\n"
    return atomic_write(path, lambda f: f.write(text))
