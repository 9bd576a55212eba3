"""Atomic checkpoints of every module's learned parameters (``.npz``).

A checkpoint holds, per module ``NAME``: ``NAME.w`` (value weights, (n,)), ``NAME.W`` (policy
mean weights, (2, n)) and ``NAME.sigma`` (scalar), plus ``__meta__``: a JSON text with the
format version, the module names, periods and shapes, the parameter hash
(:func:`~clis_learner.core.config.params_hash`) and any caller metadata (episode count, seed...).
No pickles: it loads with ``allow_pickle=False``.

The bytes are those of the content: the entries' times in the zip are fixed (1980-01-01, as
a reproducible build's), so the same parameters and metadata give the same file.

Saving is atomic: the file is written to a temporary file in the same folder, flushed and
fsync'ed, then renamed over the target with :func:`os.replace` (atomic on POSIX), and the
folder is fsync'ed. A crash or an exception at any point leaves either the old checkpoint or
the new one, never a mix; the temporary file is removed on error.

Loading validates before it changes anything: every module present, every shape equal, every
value finite, sigma > 0, and (optionally) the same parameter hash.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import json
import os
from pathlib import Path
import tempfile
from typing import Any
import zipfile

from clis_modules.core.modules import ModuleCore
import numpy as np

__all__ = ['CheckpointError', 'FORMAT_VERSION', 'save_checkpoint', 'load_checkpoint']

#: Version of the checkpoint layout.
FORMAT_VERSION = 1
#: The time of every zip entry (the earliest a zip holds): not the time it was written.
ZIP_TIME = (1980, 1, 1, 0, 0, 0)


class CheckpointError(ValueError):
    """The checkpoint is missing, unreadable, or does not fit the modules."""


def _umask() -> int:
    """The process's umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def save_checkpoint(path: str | os.PathLike, modules: Sequence[ModuleCore],
                    params_hash: str = '', metadata: Mapping[str, Any] | None = None) -> Path:
    """Write the modules' parameters to ``path`` atomically.

    Parameters
    ----------
    path : path-like
        Target file (conventionally ``*.npz``); its folder must exist.
    modules : sequence of ModuleCore
    params_hash : str
        Identifies the configuration (``params_hash(ClisParams)``).
    metadata : Mapping, optional
        JSON-serialisable extras stored under ``meta['extra']``.

    Returns
    -------
    Path
        The path written.
    """
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    info = []
    for m in modules:
        arrays[f'{m.name}.w'] = np.asarray(m.w, dtype=np.float64)
        arrays[f'{m.name}.W'] = np.asarray(m.W, dtype=np.float64)
        arrays[f'{m.name}.sigma'] = np.asarray(m.sigma, dtype=np.float64)
        info.append({'name': m.name, 'period': m.period, 'n': m.n, 'learned': m.learned})
    meta = {'version': FORMAT_VERSION, 'modules': info, 'params_hash': params_hash,
            'extra': dict(metadata or {})}
    arrays['__meta__'] = np.asarray(json.dumps(meta, sort_keys=True))
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        # mkstemp makes the file 0600 (private while it is a temporary file); the checkpoint
        # gets the mode of every other file the project writes (0666 less the umask)
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, 'wb') as fh:
            _savez(fh, arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    _fsync_dir(path.parent)
    return path


def _savez(fh, arrays: Mapping[str, np.ndarray]) -> None:
    """:func:`numpy.savez` (the same layout: one ``NAME.npy`` per array, stored), with
    :data:`ZIP_TIME` as every entry's time."""
    with zipfile.ZipFile(fh, 'w', zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, value in arrays.items():
            info = zipfile.ZipInfo(f'{name}.npy', date_time=ZIP_TIME)
            with zf.open(info, 'w', force_zip64=True) as entry:
                np.lib.format.write_array(entry, np.asanyarray(value), allow_pickle=False)


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:                    # e.g. not permitted on this platform: best effort
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def load_checkpoint(path: str | os.PathLike, modules: Sequence[ModuleCore],
                    params_hash: str | None = None) -> dict[str, Any]:
    """Load parameters saved by :func:`save_checkpoint` into ``modules`` (all or nothing).

    Parameters
    ----------
    path : path-like
    modules : sequence of ModuleCore
        Every one must be in the checkpoint with the same shapes.
    params_hash : str, optional
        When given, the checkpoint's hash must equal it.

    Returns
    -------
    dict
        The checkpoint's metadata (``version``, ``modules``, ``params_hash``, ``extra``).

    Raises
    ------
    CheckpointError
        Missing/unreadable file, missing module, wrong shape, non-finite value, hash mismatch.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except FileNotFoundError:
        raise CheckpointError(f'{path}: no such checkpoint') from None
    except Exception as exc:  # noqa: BLE001 - any unreadable file is a checkpoint error
        raise CheckpointError(f'{path}: not a readable checkpoint ({exc})') from None
    try:
        meta = json.loads(str(data.pop('__meta__')))
    except (KeyError, ValueError):
        raise CheckpointError(f'{path}: no valid metadata') from None
    if meta.get('version') != FORMAT_VERSION:
        raise CheckpointError(f'{path}: format version {meta.get("version")}, '
                              f'expected {FORMAT_VERSION}')
    if params_hash is not None and meta.get('params_hash') != params_hash:
        raise CheckpointError(f'{path}: saved with parameters {meta.get("params_hash")!r}, '
                              f'expected {params_hash!r}')
    new = {}
    for m in modules:
        for key, shape in (('w', (m.n,)), ('W', (2, m.n)), ('sigma', ())):
            name = f'{m.name}.{key}'
            if name not in data:
                raise CheckpointError(f'{path}: no {name} (holds {sorted(data)})')
            a = data[name]
            if a.shape != shape:
                raise CheckpointError(f'{path}: {name} has shape {a.shape}, expected {shape}')
            if not np.all(np.isfinite(a)):
                raise CheckpointError(f'{path}: {name} holds non-finite values')
            new[name] = a.astype(np.float64)
        if not new[f'{m.name}.sigma'] > 0.0:
            raise CheckpointError(f'{path}: {m.name}.sigma must be > 0')
    for m in modules:                  # everything validated: now assign
        m.w = new[f'{m.name}.w']
        m.W = new[f'{m.name}.W']
        m.sigma = float(new[f'{m.name}.sigma'])
    return meta
