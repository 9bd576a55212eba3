"""The command line: ``clis`` and its subcommands.

This module is the ``clis`` entry point (its parser and ``main``); :mod:`~clis_app.cli.help`
is its help formatter, :mod:`~clis_app.cli.ctrl_c` how a Ctrl-C ends a command,
:mod:`~clis_app.cli.errors` the one-line error exit, :mod:`~clis_app.cli.doctor` and
:mod:`~clis_app.cli.arena` two subcommands; the others live in the room of their job
(:mod:`clis_app.graph`, :mod:`clis_app.experiments`, :mod:`clis_app.study`,
:mod:`clis_app.bags`). Every subcommand first configures DDS for this machine only (loopback
Fast DDS profile, own ROS_DOMAIN_ID) unless ``--network`` is given, so that nothing it starts
talks to other hosts.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from typing import NoReturn

# One BLAS thread per process, set before numpy loads: `clis experiment` runs one process per
# core, and OpenBLAS threads on top of that oversubscribe the cores (the place module's
# localization update was several times slower with 2 workers).
for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

from clis_app.cli import ctrl_c  # noqa: E402
from clis_app.cli.help import HelpFormatter  # noqa: E402
from clis_app.graph.ros_env import apply_ros_env  # noqa: E402

EPILOG = """\
examples:
  clis doctor                      check the ROS 2 setup: distro, rmw, DDS profile, pub/sub
  clis --domain-id 7 doctor        same, on a chosen ROS_DOMAIN_ID
  clis --network doctor            opt in to DDS on all interfaces (e.g. a real robot)
  clis experiment --help           the paper's experiments, headless (Fig. 3-5)
  clis report results/paper        tables of measured results from experiment folders
  clis arena generate --seed 7     an arena layout drawn from a seed (clis arena --help)
  clis study config/study.yaml --out results/study   a grid of experiments (clis study --help)
  clis run --record bags/NAME      record the run as a bag; clis bag info / replay / learn it
"""


class Parser(argparse.ArgumentParser):
    """An argument error is one line on stderr, naming the option, and exit code 2 (argparse's
    own prints the whole usage first); the subcommands' parsers are of this class too."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f'{self.prog}: {message} (see {self.prog} --help)\n')


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog='clis', description='CLIS with asynchronous modules on ROS 2 (Uchibe & Doya).',
        epilog=EPILOG, formatter_class=HelpFormatter)
    parser.add_argument('--network', action='store_true',
                        help='allow DDS traffic on all interfaces (off: loopback only)')
    parser.add_argument('--domain-id', type=int, metavar='N',
                        help='ROS_DOMAIN_ID to use (None: $ROS_DOMAIN_ID or a random 1-100)')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    sub.required = True
    sub.add_parser('doctor', help='print the ROS/DDS setup and check two processes talk')
    for register in _extra_commands():
        register(sub)
    return parser


def _extra_commands() -> list:
    """Subcommands contributed by other modules (each a ``register(subparsers)``)."""
    from clis_app.bags import commands as bags
    from clis_app.cli import arena as arena_cli
    from clis_app.experiments import compare, experiment, report
    from clis_app.graph import run as graph_cli
    from clis_app.study import study
    return [experiment.register, report.register, graph_cli.register, compare.register,
            bags.register, arena_cli.register, study.register]


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        parser.error(f'--domain-id {args.domain_id} is out of range [0, 232]')
    apply_ros_env(network=args.network, domain_id=args.domain_id)
    previous = ctrl_c.install()                  # a Ctrl-C is remembered (clis_app.cli.ctrl_c)
    try:
        if args.command == 'doctor':
            from clis_app.cli.doctor import run_doctor
            code = run_doctor()
        else:
            code = int(args.func(args) or 0)
        if not ctrl_c.interrupted():
            return code
    except KeyboardInterrupt:
        pass
    except BrokenPipeError:
        # the reader of stdout went away (`clis ... | head`): what it read is what it wanted;
        # stdout goes to /dev/null so that Python's exit does not fail flushing it
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    # Ctrl-C: one line and the shell's code for SIGINT, for every subcommand (what was written
    # is complete: results are written atomically; `--resume` continues)
    print(f'\nclis {args.command}: interrupted', file=sys.stderr)
    return 130


if __name__ == '__main__':
    sys.exit(main())
