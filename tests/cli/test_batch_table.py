"""``lio batch``'s table at 80 columns: no line longer, every reason whole (folded, never cut), what went wrong
first and paths relative to where the batch ran."""

import io
from pathlib import Path

from rich.console import Console

from lio_cli.batch.commands import KEY_METRICS
from lio_cli.batch.summary import Summary
from lio_cli.cli import batch as batch_cli
from lio_cli.cli import common


def _run(name: str, log: Path, status: str, reason: str = "", exit_class: str = "ok", **metrics) -> dict:
    return {"name": name, "group": None, "command": "odom", "log": str(log), "status": status,
            "exit_class": exit_class, "exit_code": 0 if status == "ok" else 2, "reason": reason, "time_s": 1.25,
            "attempts": 1, "worker": "h:1", "folder": None, "metrics": {**dict.fromkeys(KEY_METRICS), **metrics}}


def _table(monkeypatch, summary: Summary) -> list[str]:
    buf = io.StringIO()
    monkeypatch.setattr(common.err_console, "_console", Console(file=buf, width=80, highlight=False))
    batch_cli._tables(summary)
    return buf.getvalue().splitlines()


def test_the_table_fits_80_columns_with_the_reason_whole_and_first(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    logs = tmp_path / "logs"
    reason = (f"{logs / 'bad.bag'}: cannot open as ros1 log (the bag index points past the end of the file: "
              f"truncated?); see {logs / 'bad.bag'} with lio info")
    ok = _run("walk_a_long_name", logs / "walk_a.bag", "ok", scans_total=100, scans_used=100, ate_m=0.0199,
              rpe_m=0.024)
    summary = Summary(tmp_path / "out", "2 local processes", [ok, _run("bad", logs / "bad.bag", "failed", reason,
                                                                          "input")], 3.5)
    lines = _table(monkeypatch, summary)
    assert max(len(line) for line in lines) <= 80, "\n".join(lines)
    head = next(i for i, line in enumerate(lines) if "reason" in line)
    at = lines[head].index("reason")
    column = " ".join(" ".join(line[at:].split()) for line in lines[head + 2:] if line[at:].strip())
    assert column == ("cannot open as ros1 log (the bag index points past the end of the file: truncated?); see "
                      "logs/bad.bag with lio info (input)")
    assert lines[head + 2].split()[:2] == ["walk_a_long_name", "ok"] and "0.0199" in lines[head + 2]


def test_no_reason_column_when_every_run_went_well(tmp_path, monkeypatch):
    ok = _run("walk", tmp_path / "walk.bag", "ok", scans_total=70, scans_used=70)
    lines = _table(monkeypatch, Summary(tmp_path, "this process", [ok], 1.0))
    header = next(line for line in lines if "status" in line)
    assert header.split() == ["run", "status", "time", "s", "scans"]
    assert any(line.split() == ["walk", "ok", "1.2", "70/70"] for line in lines)
