"""Writing output so that a reader sees all of it or none, and never a user's file lost.

A set of files (a plan, a folder of pictures) is first written into a fresh hidden
sibling folder ``.<name>.sdit-new-<8 chars>``; only when every file is on disk does it
take the place of the output folder, by one atomic exchange of the two names
(``renameat2(RENAME_EXCHANGE)``; where the file system lacks it, two renames whose
interruption the next run repairs).  The old content then sits in the hidden folder
and is removed.

Safety rules:

- Every output folder carries a marker file, :data:`MARKER`, naming the command that
  wrote it and every file it wrote.  ``force`` replaces a folder only when it is
  empty or holds nothing but an earlier output of the same command; a file the
  marker does not list (a user's ``thesis.docx``) is refused by name.
- The current directory, any folder above it, and any folder holding a path in
  ``protect`` (the config being planned) are never replaced.
- Leftovers of an interrupted run (hidden ``.<name>.sdit-new-*`` / ``.sdit-old-*``
  folders next to the output) are removed by the next run; if the interruption fell
  between the two renames of the fallback, the old output is put back first.
- Files and folders are created with the user's umask (0666/0777 masked), as any
  other program writes them.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import re
import secrets
import shutil
from pathlib import Path

from .errors import OutputError

#: Name of the marker file in every output folder.
MARKER = ".sdit-path-output"
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _oserror(target: Path, exc: OSError, doing: str = "cannot write") -> OutputError:
    reason = exc.strerror or str(exc)
    if exc.errno == errno.ENOSPC:
        reason = "no space left on the device"
    elif exc.errno == errno.EDQUOT:
        reason = "disk quota exceeded"
    return OutputError(f"{target}: {doing}: {reason}")


def _write(path: Path, content: str | bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = content if isinstance(content, bytes) else content.encode("utf-8")
    with open(path, "wb") as fh:  # 0666 & ~umask
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def _marker_text(command: str, files: dict[str, str | bytes]) -> str:
    return json.dumps({"written_by": "sdit-path", "command": command,
                       "files": sorted(files)}, indent=1) + "\n"


def _leftovers(out: Path) -> list[Path]:
    """Hidden folders an interrupted run of ours left next to ``out``."""
    pattern = re.compile(rf"\.{re.escape(out.name)}\.sdit-(new|old)-[0-9a-f]{{8}}")
    try:
        return sorted(p for p in out.parent.iterdir()
                      if pattern.fullmatch(p.name) and p.is_dir() and not p.is_symlink())
    except OSError:
        return []


def _recover(out: Path) -> None:
    """Put back an old output lost between the two renames of the fallback swap, then
    remove the leftovers of interrupted runs."""
    left = _leftovers(out)
    if not os.path.lexists(out):
        old = [p for p in left if ".sdit-old-" in p.name and (p / MARKER).is_file()]
        if old:
            os.rename(old[-1], out)
            left.remove(old[-1])
    for p in left:
        shutil.rmtree(p, ignore_errors=True)


def _allowed_files(out: Path, command: str) -> set[str] | None:
    """Files an earlier output of ``command`` wrote into ``out`` (relative POSIX paths),
    or None when ``out`` does not hold one."""
    data = _read_marker(out)
    if data is not None:
        if (data.get("command") == command and isinstance(data.get("files"), list)
                and all(isinstance(f, str) for f in data["files"])):
            return set(data["files"]) | {MARKER}
        return None
    # outputs of sdit-path 0.1 before the marker existed
    if command == "plan":
        try:
            manifest = json.loads((out / "plan.json").read_text(encoding="utf-8"))
            if manifest.get("format") != "sdit-path/plan":
                return None
            files = {"plan.json", "config.toml"}
            for p in manifest.get("programs", []):
                files |= {p.get("file"), p.get("trajectory")} - {None}
            return {f for f in files if isinstance(f, str)}
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError, TypeError):
            return None
    if command == "preview":
        return {p.name for p in out.iterdir()
                if re.fullmatch(r"[A-Z][A-Z0-9_]*_(speed|axes|hemisphere)\.png", p.name)}
    return None


def _read_marker(out: Path) -> dict | None:
    """``out``'s marker: None when there is none, {} when the file is there but is not
    an sdit-path marker."""
    marker = out / MARKER
    if not marker.is_file() or marker.is_symlink():
        return None
    try:
        data = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return {}
    return data if isinstance(data, dict) and data.get("written_by") == "sdit-path" else {}


def _marker_command(out: Path) -> str | None:
    """The command named by ``out``'s marker, or None."""
    command = (_read_marker(out) or {}).get("command")
    return command if isinstance(command, str) else None


def _first_foreign(out: Path, allowed: set[str] | None) -> str | None:
    for root, dirs, names in os.walk(out):
        dirs.sort()
        rel_root = Path(root).relative_to(out)
        for name in sorted(names) + sorted(d for d in dirs if (Path(root) / d).is_symlink()):
            rel = (rel_root / name).as_posix()
            if allowed is None or rel not in allowed:
                return rel
    return None


def _is_within(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def check_output(out_dir: str | os.PathLike, force: bool, command: str,
                 protect: tuple[str | os.PathLike, ...] = ()) -> Path:
    """Refuse, before any work is done, an output folder that :func:`write_tree` would
    have to refuse; returns it as a Path."""
    out = Path(out_dir)
    if out.name in ("", ".", ".."):
        out = Path(os.path.abspath(out))
    try:
        here = Path.cwd().resolve()
    except OSError:
        here = None
    resolved = out.resolve()
    if here is not None and _is_within(here, resolved):
        raise OutputError(f"{out_dir}: is the current directory or above it; name a new "
                          f"subfolder for the output (e.g. --out {command}-out)")
    for p in protect:
        if p and _is_within(Path(p).resolve(), resolved):
            raise OutputError(f"{out_dir}: holds {p}, which this run reads; choose another "
                              f"output folder")
    if out.is_symlink():
        raise OutputError(f"{out_dir}: is a symbolic link; give the folder it points to")
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a directory")
    if out.is_dir():
        try:
            empty = not any(p.name != MARKER for p in out.iterdir())
        except OSError as exc:
            raise _oserror(out, exc, "cannot read") from None
        if not empty:
            if not force:
                raise OutputError(f"{out_dir}: directory is not empty; pass --force to replace "
                                  f"an earlier sdit-path {command} output")
            other = _marker_command(out)
            if other is not None and other != command:
                raise OutputError(f"{out_dir}: holds an output of sdit-path {other}; --force "
                                  f"replaces only an earlier {command} output (choose another "
                                  f"--out)")
            foreign = _first_foreign(out, _allowed_files(out, command))
            if foreign is not None:
                raise OutputError(
                    f"{out_dir}: holds {foreign}, which sdit-path {command} did not write; "
                    f"--force replaces only an earlier {command} output (move the file away or "
                    f"choose another --out)")
    return out


def _exchange(a: Path, b: Path) -> bool:
    """Atomically exchange two paths; False where the system cannot."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err))


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_tree(out_dir: str | os.PathLike, files: dict[str, str | bytes], force: bool = False,
               command: str = "plan", protect: tuple[str | os.PathLike, ...] = ()) -> Path:
    """Write ``files`` (relative path -> text or bytes) as the whole content of ``out_dir``.

    Refuses a non-empty ``out_dir`` unless ``force``; with ``force`` only an earlier
    output of ``command`` is replaced (see the module text).  Text is written as UTF-8.
    """
    out = Path(out_dir)
    for rel in files:
        p = Path(rel)
        if p.is_absolute() or ".." in p.parts or rel == MARKER:
            raise OutputError(f"{rel}: refusing to write outside {out}")
    try:
        if out.name not in ("", ".", ".."):
            _recover(out)
    except OSError as exc:
        raise _oserror(out, exc, "cannot repair an interrupted earlier run") from None
    out = check_output(out, force, command, protect)
    parent = out.resolve().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = parent / f".{out.name}.sdit-new-{secrets.token_hex(4)}"
        os.mkdir(tmp)  # 0777 & ~umask
    except OSError as exc:
        raise _oserror(out, exc, "cannot create the output directory") from None
    old: Path | None = None
    try:
        _write(tmp / MARKER, _marker_text(command, files))
        for rel, text in files.items():
            _write(tmp / rel, text)
        _fsync_dir(tmp)
        if not out.is_dir():
            os.rename(tmp, out)
        elif _exchange(tmp, out):
            old = tmp
        else:  # two renames; an interruption between them is repaired by _recover
            old = parent / f".{out.name}.sdit-old-{secrets.token_hex(4)}"
            os.rename(out, old)
            os.rename(tmp, out)
        _fsync_dir(parent)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and old.exists() and not os.path.lexists(out):
            os.rename(old, out)
        raise _oserror(out, exc) from None
    except BaseException:
        if old is None:
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return out


def write_file(path: str | os.PathLike, content: str | bytes) -> Path:
    """Write one file atomically (temporary file in the same folder, then rename), with
    the user's umask; a full disk or an unwritable folder is an :class:`OutputError`."""
    target = Path(path)
    if target.is_dir():
        raise OutputError(f"{target}: is a directory; expected a file name")
    tmp = target.parent / f".{target.name}.sdit-tmp-{secrets.token_hex(4)}"
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "xb") as fh:  # 0666 & ~umask
            fh.write(content if isinstance(content, bytes) else content.encode("utf-8"))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _oserror(target, exc) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return target
