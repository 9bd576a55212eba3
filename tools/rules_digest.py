"""SHA-256 digests of the headless runner's episode rows on a fixed small job, per condition.

The golden digests of ``test/test_coop.py`` (the rules of before the paper preset was made
literal, commit 7597987, reproduced bit for bit by two named options) come from here:

    python tools/rules_digest.py --before-literal   # today's code with those two options
    python tools/rules_digest.py --at 7597987       # that commit's own code, on this CPU

and the paper preset (no option) before and after a change, ``--at REV`` against today's:

    python tools/rules_digest.py --at 46e0749       # before the framework refactor
    python tools/rules_digest.py

The last bits of a run depend on the CPU's vector instructions (numpy's and numba's exp, log
and reductions), so a digest holds for one kind of CPU: ``--at`` extracts the commit's
``src`` and ``config`` with ``git archive`` into a temporary folder and runs the same job with
its code (it needs the repository's history). Prints one JSON object ``{condition: digest}``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
from pathlib import Path
import subprocess
import sys
import tarfile
import tempfile

REPO = Path(__file__).resolve().parent.parent
CONDITIONS = ('async', 'sync')
#: The options that give the rules of before the literal paper preset (commit 7597987).
BEFORE_LITERAL = {'learner.policy_step': 'dimensionless', 'learner.behaviour_state': 'held'}
#: Columns added to the rows since 7597987 (diagnostics, the divergence guard's), left out of
#: the digest.
LATER_COLUMNS = ('grow_share_', 'c_max_', 'diverged')


def digest(condition: str, overrides: dict, run_dir: str) -> str:
    """The digest of ``condition``'s rows: seed 3, 10 episodes of at most 20 s from A-E."""
    try:
        from clis_app.experiments.runner import JobSpec, run_job
    except ImportError:
        try:                                # a commit from before the application's rooms
            from clis_app.core.runner import JobSpec, run_job
        except ImportError:                 # a commit from before the application package
            from clis_learner.core.runner import JobSpec, run_job
    spec = JobSpec(index=0, label=condition, condition=condition, overrides=overrides,
                   sim_overrides={'episode.time_limit': 20.0}, seed=3, episodes=10,
                   eval_episodes=0, arena=None, run_dir=run_dir, block=5,
                   train_start='starts')
    rows = [{k: v for k, v in row.items() if not k.startswith(LATER_COLUMNS)}
            for row in run_job(spec).episodes]
    return hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()


def digests_at(commit: str, overrides: dict | None = None, repo: Path = REPO
               ) -> dict[str, str]:
    """The digests of ``commit``'s own code on this CPU (``overrides``: its defaults).

    Raises
    ------
    RuntimeError
        ``commit`` is not in ``repo``'s history (a shallow clone), or its run failed.
    """
    with tempfile.TemporaryDirectory(prefix='rules_digest_') as tmp:
        archive = subprocess.run(['git', '-C', str(repo), 'archive', '--format=tar', commit,
                                  'src', 'config'], capture_output=True)
        if archive.returncode != 0:
            raise RuntimeError(f'git archive {commit}: {archive.stderr.decode().strip()} '
                               '(a clone with the full history has it)')
        tar_path = Path(tmp) / 'code.tar'
        tar_path.write_bytes(archive.stdout)
        with tarfile.open(tar_path) as tar:
            tar.extractall(tmp, filter='data')
        src = Path(tmp) / 'src'
        env = dict(os.environ, CLIS_CONFIG_DIR=str(Path(tmp) / 'config'),
                   PYTHONPATH=os.pathsep.join([str(p) for p in sorted(src.iterdir())
                                               if p.is_dir()]
                                              + [os.environ.get('PYTHONPATH', '')]))
        run = subprocess.run([sys.executable, __file__, '--overrides',
                              json.dumps(overrides or {})], env=env,
                             capture_output=True, text=True, cwd=tmp)
        if run.returncode != 0:
            raise RuntimeError(f'{commit}: its run failed: {run.stderr.strip()[-2000:]}')
        return json.loads(run.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--at', metavar='COMMIT', help="that commit's own code (git archive)")
    group = ap.add_mutually_exclusive_group()
    group.add_argument('--before-literal', action='store_true',
                       help='the two options of the rules before 7597987')
    group.add_argument('--overrides', metavar='JSON', default='{}',
                       help="the runner's overrides as a JSON object (default {})")
    args = ap.parse_args(argv)
    overrides = BEFORE_LITERAL if args.before_literal else json.loads(args.overrides)
    if args.at:
        out = digests_at(args.at, overrides)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            out = {c: digest(c, overrides, tmp) for c in CONDITIONS}
    print(json.dumps(out, sort_keys=True))


if __name__ == '__main__':
    main()
