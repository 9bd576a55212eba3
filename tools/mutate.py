"""Break the code on purpose and check that a test catches it (a mutation table).

    python tools/mutate.py FILE OLD NEW [FILE OLD NEW ...] -- PYTEST_ARGS...

Each OLD text (exact, occurring once in FILE, a path from the repository root) is replaced by
NEW, the tests run (``source env.sh``, one process, stop at the first failure), and every file
is restored, whatever happens. A mutation that no test catches prints ``passed``.
"""

from __future__ import annotations

from pathlib import Path
import shlex
import subprocess
import sys

REPO = Path(__file__).resolve().parent.parent


def main(argv: list[str]) -> int:
    if '--' not in argv or (argv.index('--') % 3) != 0 or argv.index('--') == 0:
        print(__doc__)
        return 2
    i = argv.index('--')
    muts, args = argv[:i], argv[i + 1:]
    saved: dict[Path, str] = {}
    try:
        for k in range(0, len(muts), 3):
            f, old, new = muts[k:k + 3]
            p = REPO / f
            text = p.read_text()
            saved.setdefault(p, text)
            if text.count(old) != 1:
                print(f'{old!r} occurs {text.count(old)} times in {f}')
                return 2
            p.write_text(text.replace(old, new))
            print(f'MUTATION {f}: {old.strip()!r} -> {new.strip()!r}')
        cmd = ('source env.sh >/dev/null 2>&1 && python -m pytest -q -p no:cacheprovider '
               '-o addopts="" -x ' + ' '.join(shlex.quote(a) for a in args))
        r = subprocess.run(['bash', '-c', cmd], cwd=REPO, capture_output=True, text=True)
    finally:
        for p, text in saved.items():
            p.write_text(text)
    out = r.stdout.strip().splitlines()
    print('  tests:', ' '.join(args))
    print('  result:', out[-1] if out else r.stderr[-300:])
    for line in [x for x in out if x.startswith(('FAILED', 'ERROR', 'E  '))][:4]:
        print('   ', line[:240])
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
