"""Atomic outputs on a full device (issue 32): one ``NoSpaceError`` line naming the output, nothing left."""

from __future__ import annotations

import errno
import sqlite3

import pytest

from lio_cli.errors import NoSpaceError
from lio_cli.io.files.atomic import atomic_outputs, is_no_space, no_space_as_error


def test_a_full_device_while_writing_a_set_of_outputs_leaves_none_of_them(tmp_path):
    paths = [tmp_path / "run.tum", tmp_path / "run.config.yaml", tmp_path / "run.metrics.json"]
    with pytest.raises(NoSpaceError) as err:
        with atomic_outputs(paths) as tmps:
            tmps[0].write_text("trajectory\n")
            tmps[1].write_text("config\n")
            raise OSError(errno.ENOSPC, "No space left on device")  # the third one did not fit
    assert str(err.value) == f"no space left on device: {paths[0]}"
    assert list(tmp_path.iterdir()) == []


def test_outputs_appear_together_once_all_are_written(tmp_path):
    paths = [tmp_path / "a.txt", tmp_path / "b.txt"]
    with atomic_outputs(paths) as (a, b):
        a.write_text("a")
        b.write_text("b")
        assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == []
    assert [p.read_text() for p in paths] == ["a", "b"]


@pytest.mark.parametrize("err, full", [
    (OSError(errno.ENOSPC, "No space left on device"), True),
    (OSError(errno.EDQUOT, "Disk quota exceeded"), True),
    (sqlite3.OperationalError("database or disk is full"), True),
    (OSError(errno.EACCES, "Permission denied"), False),
    (ValueError("no"), False),
])
def test_what_counts_as_a_full_device(err, full):
    assert is_no_space(err) is full
    if full:
        with pytest.raises(NoSpaceError, match="^no space left on device: out.db3$"):
            with no_space_as_error("out.db3"):
                raise err
    else:
        with pytest.raises(type(err)):
            with no_space_as_error("out.db3"):
                raise err
