"""``lio evaluate``: the command (``command``), its GPS, time-offset and group options (``extras``) and its files
(``outputs``)."""

from .command import evaluate_cmd, register

__all__ = ["evaluate_cmd", "register"]
