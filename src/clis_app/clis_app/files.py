"""Every output file of the application written atomically: to a temporary file beside it,
then renamed over it, so that a crash or a Ctrl-C never leaves half a file (a reader sees the
old one or the new one).

The temporary file is ``.NAME.tmp`` in the same folder (same file system: the rename is
atomic). :func:`atomic_path` is the general form, for writers that take a path (matplotlib,
numpy); the others write text, bytes and CSV rows.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
import csv
import os
from pathlib import Path

__all__ = ['atomic_path', 'write_text', 'write_bytes', 'write_csv']


@contextmanager
def atomic_path(path: str | os.PathLike, fsync: bool = False) -> Iterator[Path]:
    """A temporary path to write ``path``'s new content to; renamed over ``path`` when the
    block ends without an exception (removed otherwise). ``fsync``: flushed to the disk
    first (a file that must survive a power loss: the bags' metadata)."""
    path = Path(path)
    tmp = path.with_name(f'.{path.name}.tmp')
    try:
        yield tmp
        if fsync:
            with open(tmp, 'rb+') as fh:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text(path: str | os.PathLike, text: str, fsync: bool = False) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path, fsync) as tmp:
        tmp.write_text(text)


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_csv(path: str | os.PathLike, rows: Sequence[dict] | Sequence[Sequence],
              fields: Sequence[str] | None = None) -> None:
    """Write ``rows`` to ``path`` atomically: dicts under a header (``fields``, default every
    key in order of appearance), or lists (``fields``, if given, as the header row)."""
    with atomic_path(path) as tmp, open(tmp, 'w', newline='') as fh:
        if rows and isinstance(rows[0], dict):
            names = list(fields or dict.fromkeys(k for row in rows for k in row))
            writer = csv.DictWriter(fh, fieldnames=names, extrasaction='ignore')
            writer.writeheader()
            writer.writerows(rows)
        else:
            w = csv.writer(fh)
            if fields:
                w.writerow(fields)
            w.writerows(rows)
