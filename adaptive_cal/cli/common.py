"""What every command shares, kept free of heavy imports so ``--help`` stays fast."""
from __future__ import annotations


class UserError(Exception):
    """An error the user can fix; printed without a traceback."""
