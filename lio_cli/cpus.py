"""How many CPUs this process may run on (its affinity where the OS says, else the machine's count)."""

from __future__ import annotations

import os


def usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0)) or 1
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


__all__ = ["usable_cpus"]
