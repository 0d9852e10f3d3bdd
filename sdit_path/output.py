"""Writing a set of files so that a reader sees all of them or none.

Everything is first written into a fresh sibling directory; only when every file is
on disk does that directory take the place of the output directory (one rename).  A
failure at any point removes the temporary directory and leaves the old output as it
was.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from .errors import OutputError


def _write(path: Path, content: str | bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = content if isinstance(content, bytes) else content.encode("ascii")
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def write_tree(out_dir: str | os.PathLike, files: dict[str, str | bytes],
               force: bool = False) -> Path:
    """Write ``files`` (relative path -> text or bytes) as the whole content of ``out_dir``.

    Refuses a non-empty ``out_dir`` unless ``force``; with ``force`` its old content
    is replaced as a whole.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise OutputError(f"{out}: directory is not empty; pass --force to replace its content")
    for rel in files:
        p = Path(rel)
        if p.is_absolute() or ".." in p.parts:
            raise OutputError(f"{rel}: refusing to write outside {out}")
    parent = out.resolve().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.new-", dir=parent))
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the output directory: {exc.strerror}") from None
    backup: Path | None = None
    try:
        for rel, text in files.items():
            _write(tmp / rel, text)
        if out.is_dir():
            backup = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=parent))
            backup.rmdir()
            os.rename(out, backup)
        os.rename(tmp, out)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if backup is not None and backup.exists() and not out.exists():
            os.rename(backup, out)
        raise OutputError(f"{out}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if backup is not None and backup.exists() and not out.exists():
            os.rename(backup, out)
        raise
    if backup is not None:
        shutil.rmtree(backup, ignore_errors=True)
    return out


def write_file(path: str | os.PathLike, content: str | bytes, force: bool = True) -> Path:
    """Write one file atomically (temporary file in the same folder, then rename)."""
    target = Path(path)
    if target.exists() and not force:
        raise OutputError(f"{target}: exists; pass --force to replace it")
    if target.is_dir():
        raise OutputError(f"{target}: is a directory")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    except OSError as exc:
        raise OutputError(f"{target}: cannot write: {exc.strerror}") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(content if isinstance(content, bytes) else content.encode("utf-8"))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
