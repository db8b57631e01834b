"""What every command shares, kept free of heavy imports so ``--help`` stays fast."""
from __future__ import annotations

import argparse


class UserError(Exception):
    """An error the user can fix; printed without a traceback."""


class DefaultsShown(argparse.HelpFormatter):
    """Appends "(default: X)" to an option's help only where X is a real default: not for
    required options, flags (store_true/false), or options whose default is None or suppressed,
    and not where the help already places ``%(default)``."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("%(default)" in text or action.required or default is None or default is False
                or default is argparse.SUPPRESS or action.nargs == 0):
            return text
        if action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            return text + " (default: %(default)s)"
        return text
