"""``clis run`` interrupted (Ctrl-C) at random moments and resumed, into the same ``--out``.

A tiny run (the innate module, 80 episodes of at most 4 s: a few wall seconds once up) is
stopped with SIGINT :data:`INTERRUPTS` times at random moments (the first while it starts or
after one or two learned episodes, the others after one to three more learned episodes, judged
by its checkpoint, plus up to half a second), each time resumed from its checkpoint
(``--resume OUT/checkpoint.npz``, the episodes still to learn), then run to its end; the
interruptions cannot outrun the run, whatever the load. Compared with the same run
uninterrupted:

- ``episodes.csv`` is one table (one header, episodes 1..N once each, in order, N >= 20) and
  the checkpoint is at its last episode, as in the uninterrupted run;
- the episodes learned before the first interruption are the uninterrupted run's, byte for byte
  (the graph in lockstep computes the same episodes on any load).

Byte-for-byte equality of the whole table does not hold for the graph, and the test does not
claim it: a resumed run continues in a new simulator process, whose robot starts where the
wander policy puts it (not where the interrupted run's robot stood) and whose generators are
drawn from (seed, stream, first episode), not the interrupted process's states (so that a resume
does not replay episode 1's draws); the checkpoint's zip entries carry their write time.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
import random
import signal
import subprocess
import sys
import time

import numpy as np

EPISODES = 80
PARAMS = '/**:\n  ros__parameters:\n    episode: {time_limit: 4.0, wander_time: 1.0}\n'
INTERRUPTS = 4                     # each after <= 3 learned episodes (+ those a stop finishes)


def start(out: Path, params: Path, episodes: int, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'clis_learner.cli', 'run', '--condition',
                             'innate', '--episodes', str(episodes), '--params', str(params),
                             '--out', str(out), '--quiet', *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def learned(out: Path) -> int:
    """The episode of OUT's checkpoint (0 without one)."""
    path = out / 'checkpoint.npz'
    if not path.is_file():
        return 0
    with np.load(path, allow_pickle=False) as npz:
        return int(json.loads(str(npz['__meta__']))['extra']['episode'])


def resume(out: Path, params: Path) -> subprocess.Popen:
    done = learned(out)
    extra = ['--resume', str(out / 'checkpoint.npz')] if done else []
    return start(out, params, EPISODES - done, *extra)


def rows(out: Path) -> list[list[str]]:
    with open(out / 'episodes.csv', newline='') as fh:
        return list(csv.reader(fh))


def test_interrupted_and_resumed_run_keeps_one_table_and_the_uninterrupted_start(tmp_path):
    params = tmp_path / 'short.yaml'
    params.write_text(PARAMS)
    ref = tmp_path / 'ref'
    proc = start(ref, params, EPISODES)
    text, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, text

    out = tmp_path / 'run'
    rng = random.Random(23)
    interruptions, resumed, first_cut = 0, 0, None
    for k in range(INTERRUPTS):
        before = learned(out)
        resumed += before > 0
        proc = resume(out, params)
        # a random moment: while it starts (the first time, by chance), else up to half a
        # second after one of the next three episodes is learned
        j = rng.randint(0, 2) if k == 0 else rng.randint(1, 3)
        while learned(out) < before + j and proc.poll() is None:
            time.sleep(0.05)
        time.sleep(rng.uniform(0.0, 0.5) if j else rng.uniform(0.0, 3.0))
        proc.send_signal(signal.SIGINT)
        text, _ = proc.communicate(timeout=120)
        assert proc.returncode in (0, 130), text
        assert 'Traceback' not in text, text
        interruptions += proc.returncode == 130
        if first_cut is None and proc.returncode == 130:
            first_cut = learned(out)
    proc = resume(out, params)                                      # to the end
    text, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, text
    print(f'{interruptions} interruptions, {resumed} resumed from a checkpoint, the first '
          f'after episode {first_cut}')

    # (a stopping run may learn one episode more than asked: the one that ended meanwhile)
    table, expected = rows(out), rows(ref)
    assert table[0] == expected[0]
    col = table[0].index('episode')
    assert [r[col] for r in table[1:]] == [str(k) for k in range(1, len(table))], table
    assert len(table) - 1 == learned(out) >= EPISODES
    assert len(expected) - 1 == learned(ref) >= EPISODES
    assert table[1:1 + first_cut] == expected[1:1 + first_cut]
    assert interruptions == INTERRUPTS and resumed >= INTERRUPTS - 2
