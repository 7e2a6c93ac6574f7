"""The error family of lio.

Library code raises these; only ``lio_cli.cli`` turns them into a line on stderr and an exit code
(``InputError``/``ConfigError`` -> 2, ``ProcessingError`` -> 1).
"""


class LioError(Exception):
    """Base of every error lio raises on purpose."""

    exit_code = 1


class InputError(LioError):
    """Bad input: missing or corrupt file, unknown topic, wrong message type, bad data."""

    exit_code = 2


class ConfigError(LioError):
    """Bad configuration or usage: invalid option values, unreadable config file."""

    exit_code = 2


class ProcessingError(LioError):
    """Processing failed on valid input (e.g. registration diverged for good)."""

    exit_code = 1


class NoSpaceError(ProcessingError):
    """The output's device is full (ENOSPC, a quota, sqlite's "database or disk is full"); nothing was left."""
