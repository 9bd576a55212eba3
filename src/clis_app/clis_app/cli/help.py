"""How the ``clis`` command and its subcommands format their ``--help``.

Its own module: ``clis`` (:mod:`clis_app.cli`) imports every subcommand's module, and each
of those formats its help with :class:`HelpFormatter`.
"""

from __future__ import annotations

import argparse

__all__ = ['HelpFormatter']


class HelpFormatter(argparse.RawDescriptionHelpFormatter,
                    argparse.ArgumentDefaultsHelpFormatter):
    """Descriptions and epilogs as written, and every option's default in its help (not for
    flags, required options and ``None`` defaults, whose help says what they mean)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.required or action.default in (None, False, []):
            return action.help or ''
        return super()._get_help_string(action)
