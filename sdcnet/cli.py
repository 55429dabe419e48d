"""How every sdcnet command (``sdc-data``, ``sdc-train``, ``sdc-eval``, ``sdc-export``,
``sdc-serve``, ``sdc-client``) ends on an error.

A user's mistake (a missing file, a bad value, a service that answered an error) is one line,
``PROG: error: MESSAGE``, and the command's exit status for it. Anything else is a bug: one line
that says so, exit status 70 (``EX_SOFTWARE``), and its traceback with ``--debug`` (which also
prints the traceback behind a user error, for a bug report).
"""

from __future__ import annotations

import argparse
import sys
import traceback
from collections.abc import Callable, Mapping

EXIT_BUG = 70  # EX_SOFTWARE in sysexits.h: an internal software error
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report it
#: The user errors of the offline commands (sdc-data, sdc-train, sdc-eval, sdc-export): a file
#: that cannot be read or written, a value that cannot be used; both exit 2, as argparse does.
FILE_AND_VALUE_ERRORS: Mapping[type[Exception], int] = {OSError: 2, ValueError: 2}


def add_debug_flag(parser: argparse.ArgumentParser, default: object = False) -> None:
    """``--debug``; ``default`` ``argparse.SUPPRESS`` where a parent parser holds it."""
    parser.add_argument(
        "--debug",
        action="store_true",
        default=default,
        help="print the traceback of any error (for bug reports)",
    )


def run_command(
    prog: str,
    command: Callable[[], int],
    user_errors: Mapping[type[Exception], int],
    debug: bool = False,
) -> int:
    """``command()``'s exit status; an exception of a type in ``user_errors`` (the first that
    matches, in order) is one line and the status it maps to, any other is a bug (see above)."""
    try:
        return command()
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:
        if debug:
            traceback.print_exc()
        status = next((s for kind, s in user_errors.items() if isinstance(exc, kind)), None)
        if status is not None:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return status
        hint = "" if debug else "; run it again with --debug for the traceback"
        print(f"{prog}: internal error (a bug): {type(exc).__name__}: {exc}{hint}", file=sys.stderr)
        return EXIT_BUG
