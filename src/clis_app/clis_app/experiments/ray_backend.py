"""``clis experiment --backend ray``: the experiment's runs as Ray tasks (docs/scale.md).

Each run (condition, seed) is one task: :func:`~clis_app.experiments.runner.run_job` on whichever
Ray worker gets it, into a temporary folder of that worker; the task returns the run's result
file and checkpoint as bytes and the driver writes them to ``OUT/runs/`` exactly where the
process pool writes them, so no shared file system is needed, ``--resume`` sees the same files
whichever backend wrote them, and a run's results do not depend on the backend (every random
draw comes from generators seeded by the run's seed).

Failures: a task whose worker process dies (killed, out of memory, a node lost) is retried by
Ray (``max_retries``) from the start of the run; a run's result is written once, by the driver,
when its task returns, so a retried run loses nothing and duplicates nothing. An exception
raised inside a run is not retried (it would raise again) and stops the experiment, the runs
finished so far kept for ``--resume``.

Local instance (no ``--address``): ``ray.init`` starts a small Ray on this machine with
``--workers`` CPUs, no dashboard, usage statistics off, and every Ray process bound to
127.0.0.1 (the project sends nothing off this machine by default); it stops with the
experiment. With ``--address`` the driver joins a running cluster (``ray start --head``) and
the cluster's workers run the tasks: each needs this project installed (``make setup``) at the
same commit and config, checked by the parameter hash of every result.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
import json
import logging
import os
import socket
import tempfile
from typing import Any

from clis_learner.core.config import params_hash

from clis_app import files
from clis_app.experiments.runner import JobResult, JobSpec, run_job

__all__ = ['LOCAL_ENV', 'MAX_RETRIES', 'init_ray', 'run_ray']

#: Environment of a local Ray instance: no usage statistics sent anywhere, and the node's
#: address is the loopback one, so its GCS, raylet and workers listen on 127.0.0.1 only.
LOCAL_ENV = {'RAY_USAGE_STATS_ENABLED': '0', 'RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER': '0'}
#: Times a run is restarted after its worker process died.
MAX_RETRIES = 3
#: Object store of a local instance [bytes] (results are small; Ray's minimum is 75 MiB).
_OBJECT_STORE = 100 * 2**20
#: Starts of a local instance before giving up (Ray gives its raylet 30 s to register).
_START_ATTEMPTS = 3
#: Environment of every worker (one BLAS thread: the parallelism is one run per CPU).
_WORKER_ENV = {'OPENBLAS_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1'}


def init_ray(address: str | None, workers: int) -> Any:
    """Start a local Ray instance (``address`` None) or join the cluster at ``address``.

    Returns
    -------
    module
        ``ray``, initialised.
    """
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')
    if address is None:
        os.environ.update(LOCAL_ENV)          # read by ray at import: set before it
    import ray
    common = dict(include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False,
                  runtime_env={'env_vars': _WORKER_ENV})
    if address is not None:
        ray.init(address=address, **common)
        return ray
    for attempt in range(_START_ATTEMPTS):
        try:
            ray.init(num_cpus=workers, object_store_memory=_OBJECT_STORE, **common)
            return ray
        except Exception as exc:      # ray raises a bare Exception when its raylet is late
            if 'timed out during startup' not in str(exc) or attempt + 1 == _START_ATTEMPTS:
                raise
            ray.shutdown()            # a loaded machine: Ray waits only 30 s; start again
    return ray


def _job_task(spec: dict, queue: Any) -> tuple[bytes, bytes | None, str]:
    """One run on a Ray worker: its result file, checkpoint and the worker's ``host:pid``."""
    where = f'{socket.gethostname()}:{os.getpid()}'

    def report(episodes: int, note: str) -> None:
        queue.put(('progress', spec['index'], episodes, f'{note} [worker {where}]'))

    with tempfile.TemporaryDirectory(prefix='clis-run-') as tmp:
        local = JobSpec(**{**spec, 'run_dir': tmp})
        path = run_job(local, progress=report).save()
        ckpt = path.with_suffix('.npz')
        return path.read_bytes(), ckpt.read_bytes() if ckpt.is_file() else None, where


def _store(spec: JobSpec, result_bytes: bytes, ckpt: bytes | None, expected_hash: str,
           where: str) -> None:
    """Write a returned run where the process pool writes it (``spec.result_path()``)."""
    result = JobResult(**json.loads(result_bytes))
    if result.params_hash != expected_hash:
        raise RuntimeError(
            f'{spec.label} seed {spec.seed} ran on worker {where} with other parameters '
            f'(hash {result.params_hash} != {expected_hash}): every Ray node needs the same '
            'checkout and config/ (docs/scale.md)')
    result.spec['run_dir'] = spec.run_dir
    if ckpt is not None:
        files.write_bytes(spec.result_path().with_suffix('.npz'), ckpt)
    result.save()                             # atomic; last, so done() implies the checkpoint


def run_ray(todo: list[JobSpec], workers: int, address: str | None,
            progress: Any, poll: float = 0.5,
            on_start: Callable[[Any], None] | None = None) -> None:
    """Run ``todo`` as Ray tasks; each result is stored as soon as its task returns.

    Parameters
    ----------
    progress : clis_app.experiments.pool.Progress
        Gets ``update(job, episodes, note)`` and ``finish(job, episodes, note)``.
    on_start : callable, optional
        Called with the ``ray`` module once it is initialised (tests).

    Raises
    ------
    Exception
        The first run that failed (after Ray's retries of a dead worker); the runs stored
        before it stay in ``OUT/runs``.
    """
    ray = init_ray(address, workers)
    try:
        from ray.util.queue import Empty, Queue
        if on_start is not None:
            on_start(ray)
        task = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(
            _job_task)
        queue = Queue()
        remap = {s.index: k for k, s in enumerate(todo)}
        hashes = {s.index: params_hash(s.load()[0]) for s in todo}
        pending = {task.remote(asdict(s), queue): s for s in todo}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=poll)
            while True:
                try:
                    _, index, episodes, note = queue.get_nowait()
                except Empty:
                    break
                progress.update(remap[index], episodes, note)
            for ref in ready:
                spec = pending.pop(ref)
                result_bytes, ckpt, where = ray.get(ref)
                _store(spec, result_bytes, ckpt, hashes[spec.index], where)
                progress.finish(remap[spec.index], spec.episodes,
                                f'{spec.label} seed {spec.seed} done [worker {where}]')
    finally:
        ray.shutdown()
