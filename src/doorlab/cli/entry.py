"""The ``doorlab`` console script: Ctrl-C, SIGTERM and SIGHUP are handled from its start.

Importing the CLI (pydrake, numpy) takes about half a second; a signal then would print an
import traceback. So the signals are blocked while it imports (this module and ``doorlab``'s
``__init__`` import nothing heavy), the CLI's handlers are installed, and a signal that
arrived meanwhile is delivered: a one-line "interrupted" and the exit code 128 + signum.
"""

from __future__ import annotations

import signal
import sys

_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def main() -> int:
    """Entry point of the ``doorlab`` console script; returns the exit code."""
    from doorlab.errors import interrupt_exit_code

    previous = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
    try:
        from doorlab.cli.parser import main as cli_main
        from doorlab.runtime.interrupts import install_signal_handlers

        install_signal_handlers()
    finally:
        try:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)  # a held signal raises here
        except KeyboardInterrupt as e:
            print("doorlab: interrupted", file=sys.stderr)
            return interrupt_exit_code(e)
    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
