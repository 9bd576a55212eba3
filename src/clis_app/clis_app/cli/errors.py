"""The one-line error exit of every ``clis`` subcommand: ``clis COMMAND: message`` on stderr
(a message of several lines, a YAML parser's say, joined into one) and exit code 2."""

from __future__ import annotations

import sys

__all__ = ['EXIT_USAGE', 'fail']

#: Exit code of a bad argument or input.
EXIT_USAGE = 2


def fail(command: str, message: object, code: int = EXIT_USAGE) -> int:
    """Print ``clis COMMAND: MESSAGE`` as one line on stderr; return ``code``."""
    print(f'clis {command}: {" ".join(str(message).split())}', file=sys.stderr)
    return code
