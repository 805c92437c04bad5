"""`loopclosure` entry point: builds the command tree and turns user errors into one line.

Commands are defined in one module per family (each has ``register(app)``).
Command groups of packages above `slam` in the dependency order (`evaluation`)
register through the ``loopclosure.commands`` entry-point group, so `slam` never
imports them; such a plugin may also add a report to `loopclosure run`
(`slam.cli.run_command.add_run_reporter`), as `evaluation` adds its demo report.

Exit status: 0 success, 2 user error (``error: ...`` on stderr, no traceback),
130 interrupted.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Sequence
from importlib.metadata import entry_points
from types import ModuleType

import typer

from data.errors import DataWarning, UserError
from slam.cli import data_commands, graph_commands, run_command

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def build_app() -> typer.Typer:
    """The full command tree: own commands, then the registered plugins (whose run
    reporters replace those of an app built before)."""
    app = typer.Typer(
        name="loopclosure",
        help="SLAM loop closure on a gtsam factor graph: place recognition with shape matchers.",
        add_completion=False,
        no_args_is_help=True,
        pretty_exceptions_enable=False,
        context_settings={"help_option_names": ["-h", "--help"]},
    )
    for module in _own_command_modules():
        module.register(app)
    for ep in entry_points(group="loopclosure.commands"):
        ep.load()(app)
    return app


def _own_command_modules() -> list[ModuleType]:
    return [data_commands, graph_commands, run_command]


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    if issubclass(category, DataWarning):
        print(f"warning: {message}", file=sys.stderr)
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


_default_showwarning = warnings.showwarning


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit status (also used as the console script)."""
    warnings.showwarning = _show_warning
    warnings.simplefilter("always", DataWarning)
    command = typer.main.get_command(build_app())
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        result = command.main(args=args, prog_name="loopclosure", standalone_mode=False)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except typer.TyperException as exc:  # usage errors of the vendored click
        message = exc.format_message()
        if type(exc).__name__ == "NoArgsIsHelpError":
            print(message, file=sys.stderr)
        else:
            print(f"error: {message}", file=sys.stderr)
        return exc.exit_code
    except (typer.Abort, KeyboardInterrupt):
        print("error: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0
    return int(result) if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())
