"""The ``lio`` console script: Ctrl-C and SIGTERM while the CLI's modules load (the command's too) take effect
once they are loaded, as one line and exit 130/143. Raised inside an import they printed a traceback, or were
lost when they landed in one of the import system's callbacks ("Exception ignored in ...")."""

from __future__ import annotations

import gc
import signal
import sys

_WORDS = {signal.SIGINT: ("interrupted", 130), signal.SIGTERM: ("terminated", 143)}


def _terminated_at_start_up(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    raise SystemExit(_stop(signal.SIGTERM))


_terminated_at_start_up.lio_start_up = True  # cli.app.main replaces it with its own handler


def _stop(signum: int) -> int:
    what, code = _WORDS[signum]
    sys.stderr.write(f"lio: {what}; nothing half-written was left behind\n")
    return code


def entry() -> None:  # pragma: no cover - console script
    gc.disable()  # as cli.app.entry: no cyclic collection while the modules load
    caught: list[int] = []
    own_term = signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    if own_term:
        signal.signal(signal.SIGTERM, lambda signum, frame: caught.append(signum))
    from . import app

    wanted = next((a for a in sys.argv[1:] if not a.startswith("-")), None)
    if wanted in app.COMMANDS:
        app.register_commands([wanted])
    signal.signal(signal.SIGINT, signal.default_int_handler)
    if own_term:
        signal.signal(signal.SIGTERM, _terminated_at_start_up)
    if caught:
        sys.exit(_stop(caught[0]))
    app.entry()


__all__ = ["entry"]
