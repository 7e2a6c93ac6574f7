"""The ``lio`` console script: Ctrl-C and SIGTERM during start-up (while the CLI's modules load) end the process
with one line and exit 130/143, not a traceback from inside an import."""

from __future__ import annotations

import signal
import sys


def _terminated_at_start_up(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    raise SystemExit(_stop("terminated", 143))


_terminated_at_start_up.lio_start_up = True  # cli.app.main replaces it with its own handler


def _stop(what: str, code: int) -> int:
    sys.stderr.write(f"lio: {what}; nothing half-written was left behind\n")
    return code


def entry() -> None:  # pragma: no cover - console script
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _terminated_at_start_up)
    try:
        from .app import entry as run
    except KeyboardInterrupt:
        sys.exit(_stop("interrupted", 130))
    run()


__all__ = ["entry"]
