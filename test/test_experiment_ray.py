"""clis experiment --backend ray: same results as the process pool, loopback only, a killed Ray
worker's run is retried and nothing is lost. Each test starts a local Ray instance
(2 CPUs, about 10 s)."""

from __future__ import annotations

import json
import os
from pathlib import Path
import shutil
import signal

from clis_app.cli import build_parser
from clis_app.experiments import experiment, ray_backend
import pytest

ARGS = ['--conditions', 'innate,place', '--episodes', '60', '--block', '30', '--seeds', '2',
        '--eval-episodes', '1', '--workers', '2', '--quiet']


def _run(out: Path, *extra: str) -> int:
    args = build_parser().parse_args(['experiment', *ARGS, '--out', str(out), *extra])
    return args.func(args)


def _runs(out: Path) -> dict[str, str]:
    """The run files (as canonical JSON text) without their wall-clock seconds and folder."""
    runs = {}
    for path in sorted((out / 'runs').glob('*.json')):
        data = json.loads(path.read_text())
        data.pop('seconds')
        data['spec'].pop('run_dir')
        runs[path.name] = json.dumps(data, sort_keys=True)
    return runs


@pytest.fixture(scope='module')
def pool_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('pool')
    assert _run(out) == 0
    return out


def _descendants(root: int) -> set[int]:
    parent = {}
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue
        parent[int(stat.parent.name)] = int(fields[1])
    out, frontier = {root}, {root}
    while frontier:
        frontier = {p for p, pp in parent.items() if pp in frontier} - out
        out |= frontier
    return out


def _bound_addresses(pids: set[int]) -> list[str]:
    """Local addresses of the TCP listening and UDP sockets of ``pids`` (from /proc)."""
    inodes = set()
    for pid in pids:
        try:
            for fd in Path(f'/proc/{pid}/fd').iterdir():
                link = os.readlink(fd)
                if link.startswith('socket:['):
                    inodes.add(link[8:-1])
        except OSError:
            continue
    addresses = []
    for table in ('tcp', 'tcp6', 'udp', 'udp6'):
        lines = Path(f'/proc/net/{table}').read_text().splitlines()[1:]
        for line in lines:
            f = line.split()
            local, state, inode = f[1], f[3], f[9]
            if inode not in inodes or (table.startswith('tcp') and state != '0A'):
                continue
            hexip = local.split(':')[0]
            if len(hexip) == 8:
                ip = '.'.join(str(int(hexip[i:i + 2], 16)) for i in (6, 4, 2, 0))
            else:   # four little-endian 32-bit words
                words = [bytes.fromhex(hexip[i:i + 8])[::-1] for i in range(0, 32, 8)]
                raw = b''.join(words)
                ip = ('::ffff:' + '.'.join(str(b) for b in raw[12:])
                      if raw[:12] == b'\0' * 10 + b'\xff\xff' else raw.hex())
            addresses.append(f'{table} {ip}')
    return addresses


def _is_loopback(address: str) -> bool:
    ip = address.split()[1]
    return (ip.startswith('127.') or ip.startswith('::ffff:127.')
            or ip == '00000000000000000000000000000001')


def test_ray_backend_gives_the_process_pool_results_on_loopback_only(pool_run, tmp_path,
                                                                     monkeypatch):
    seen = {}
    init = ray_backend.init_ray

    def checked_init(address, workers):
        ray = init(address, workers)
        seen['cpus'] = ray.cluster_resources().get('CPU')
        seen['addresses'] = _bound_addresses(_descendants(os.getpid()))
        return ray

    monkeypatch.setattr(ray_backend, 'init_ray', checked_init)
    out = tmp_path / 'ray'
    assert _run(out, '--backend', 'ray') == 0
    assert seen['cpus'] == 2                                  # --workers 2: a small instance
    assert seen['addresses'], 'no Ray socket found'
    assert all(_is_loopback(a) for a in seen['addresses']), seen['addresses']
    for name in ('episodes.csv', 'eval.csv'):
        assert (out / name).read_bytes() == (pool_run / name).read_bytes()
    assert _runs(out) == _runs(pool_run)
    for npz in (pool_run / 'runs').glob('*.npz'):
        assert (out / 'runs' / npz.name).read_bytes() == npz.read_bytes()


def test_killed_ray_worker_is_retried_and_resume_crosses_backends(pool_run, tmp_path,
                                                                   monkeypatch):
    out = tmp_path / 'ray'
    (out / 'runs').mkdir(parents=True)
    # one run already done by the process pool: --resume keeps it, Ray runs the other three
    for ext in ('json', 'npz'):
        shutil.copy(pool_run / 'runs' / f'improved_innate__s0.{ext}', out / 'runs')
    killed, finished = {}, {}
    update, finish = experiment.Progress.update, experiment.Progress.finish

    def update_and_kill(self, job, episodes, note):
        # the first progress report of the first place run: kill its worker, by its pid
        if not killed and note.startswith('improved:place') and '[worker ' in note:
            where = note.rsplit('[worker ', 1)[1].rstrip(']')
            killed.update(job=job, where=where, episodes=episodes)
            os.kill(int(where.rsplit(':', 1)[1]), signal.SIGKILL)
        update(self, job, episodes, note)

    def finish_and_note(self, job, episodes, note):
        finished[job] = note
        finish(self, job, episodes, note)

    monkeypatch.setattr(experiment.Progress, 'update', update_and_kill)
    monkeypatch.setattr(experiment.Progress, 'finish', finish_and_note)
    assert _run(out, '--backend', 'ray', '--resume') == 0
    assert killed, 'no place run reported progress'
    assert killed['episodes'] < 60                            # killed mid-run
    assert len(finished) == 3                                 # the resumed run was not rerun
    assert f'[worker {killed["where"]}]' not in finished[killed['job']]   # rerun elsewhere
    for name in ('episodes.csv', 'eval.csv'):
        assert (out / name).read_bytes() == (pool_run / name).read_bytes()
    assert _runs(out) == _runs(pool_run)
    assert not list((out / 'runs').glob('.*.tmp'))


def test_longest_runs_start_first_and_the_order_is_stable(tmp_path):
    from clis_app.experiments.runner import JobSpec

    def spec(i, condition, episodes=100):
        return JobSpec(index=i, label=condition, condition=condition, overrides={},
                       sim_overrides={}, seed=i, episodes=episodes, eval_episodes=1, arena=None,
                       run_dir=str(tmp_path))

    specs = [spec(0, 'innate'), spec(1, 'view'), spec(2, 'async'), spec(3, 'place'),
             spec(4, 'async'), spec(5, 'innate', episodes=1000)]
    order = [s.index for s in experiment.longest_first(specs)]
    assert order == [5, 2, 4, 3, 0, 1]
