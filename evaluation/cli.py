"""`loopclosure eval ...` and `loopclosure bench ...`: registered through an entry point."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add the `eval` and `bench` command groups to `app`."""
