"""``clis arena``: generate an arena layout from a seed, and look at one.

``clis arena generate --seed K`` draws a layout of the paper's kind (a 3 m x 3 m floor, short
and tall obstacles, a landmark on each wall, a destination, starts A-E in the paper's
situations, checked geometrically; :mod:`cr_sim.core.layout`) and writes it in the format of
config/arena.yaml: to ``--out FILE`` or to stdout. The same seed gives the same bytes. The
file is read back by the arena loader before it is written.

``clis arena show FILE`` loads any arena file, checks its starts against the paper's
situations (A-C: the straight line clear and the destination visible; D: a short obstacle
across the straight line; E: a tall obstacle hides the destination), prints the check and the
share of the free floor from which the destination is hidden, and draws the layout with its
starts (``--png``).
"""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path
import sys

from clis_app import files
from clis_app.cli.errors import fail
from clis_app.cli.help import HelpFormatter

EPILOG = """\
examples:
  clis arena generate --seed 7 --out /tmp/gen7.yaml --png /tmp/gen7.png
  clis arena generate --seed 7                      # the file on stdout
  clis arena show config/arena.yaml --png /tmp/arena.png
  clis run --arena /tmp/gen7.yaml --condition view --episodes 50
  clis experiment --arena /tmp/gen7.yaml --conditions innate,view --out /tmp/e7
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('arena', help='generate an arena layout from a seed; check and draw one',
                       description=__doc__, epilog=EPILOG, formatter_class=HelpFormatter)
    actions = p.add_subparsers(dest='action', metavar='ACTION')
    actions.required = True
    g = actions.add_parser('generate', help='draw a layout from a seed (config/arena.yaml '
                           'format)', description=__doc__, epilog=EPILOG,
                           formatter_class=HelpFormatter)
    g.add_argument('--seed', type=int, required=True, help='the layout seed (>= 0)')
    g.add_argument('--out', type=Path, help='the arena file to write (default: stdout)')
    g.add_argument('--png', type=Path, help='also draw the layout with its starts here')
    g.set_defaults(func=main)
    s = actions.add_parser('show', help="check an arena file's starts and draw it",
                           description=__doc__, epilog=EPILOG, formatter_class=HelpFormatter)
    s.add_argument('file', type=Path, help='an arena file (config/arena.yaml format)')
    s.add_argument('--png', type=Path, help='draw the layout with its starts here')
    s.set_defaults(func=main)


#: ``clis arena: MESSAGE`` on one line, exit code 2 (:func:`clis_app.cli.errors.fail`)
_fail = partial(fail, 'arena')


def _writable(path: Path | None, flag: str) -> str:
    if path is None:
        return ''
    parent = path.parent if str(path.parent) else Path('.')
    if path.is_dir():
        return f'{flag} {path}: is a folder'
    if not parent.is_dir():
        return f'{flag} {path}: no folder {parent}'
    return ''


def main(args: argparse.Namespace) -> int:
    from cr_sim.core.arena import ArenaError, load_arena, parse_arena
    from cr_sim.core.layout import hidden_share, layout_for_seed, layout_yaml, start_situations
    from cr_sim.core.robot import load_robot_params
    radius = load_robot_params().radius
    bad = _writable(args.png, '--png')
    if args.action == 'generate':
        bad = bad or _writable(args.out, '--out')
        if args.seed < 0:
            bad = f'--seed {args.seed}: must be >= 0'
        if bad:
            return _fail(bad)
        layout = layout_for_seed(args.seed, radius)
        text = layout_yaml(layout)
        import yaml
        arena = parse_arena(yaml.safe_load(text), radius, source=f'seed {args.seed}')
        if args.out is None:
            sys.stdout.write(text)
        else:
            files.write_text(args.out, text)
            arena = load_arena(args.out, radius)        # what a run will read
            print(f'wrote {args.out}: layout seed {args.seed}, goal hidden from '
                  f'{100 * layout.hidden:.1f}% of the free floor', file=sys.stderr)
        title = f'layout seed {args.seed}'
    else:
        if not args.file.is_file():
            return _fail(f'{args.file}: no such file')
        if bad:
            return _fail(bad)
        try:
            arena = load_arena(args.file, radius)
        except ArenaError as exc:
            return _fail(str(exc))
        checks = start_situations(arena, radius)
        print(f'{args.file}: loads; goal hidden from {100 * hidden_share(arena, radius):.1f}% '
              'of the free floor')
        for name, why in checks.items():
            print(f'  {name}: {"in its situation" if not why else "NOT in its situation: " + why}')
        title = str(args.file)
    if args.png is not None:
        from clis_app.study.figures import layout_picture
        layout_picture(arena, radius, args.png, title)
        print(f'wrote {args.png}', file=sys.stderr)
    if args.action == 'show' and any(start_situations(arena, radius).values()):
        return 1
    return 0
