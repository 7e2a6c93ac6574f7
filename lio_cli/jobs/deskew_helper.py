"""The writing pass of ``lio deskew`` in a second process, beside the odometry: on two cores a run takes about
as long as its odometry alone, not the odometry plus the writing.

The parent starts the helper (``Helper.start``) before its odometry and sends it the setup, then each batch
of settled poses as the odometry settles them, then the rotation that levels the odometry's world frame.
The helper reads the log itself, writes the output log and the map to their temporary siblings, renames
them, and answers with the pass's statistics or with the error that stopped it. When the parent's end of
the pipe closes without the end message (its odometry failed, or it was interrupted) the helper discards
what it wrote. The helper's progress (scans written) comes back on the same pipe.

Messages are pickles behind a length prefix: the parent's on the helper's stdin, the helper's on its stdout
(everything else the helper prints goes to stderr).
"""

from __future__ import annotations

import os
import pickle
import struct
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

from ..errors import LioError, ProcessingError

_HEADER = struct.Struct("<Q")
_PROGRESS_S = 0.1  # the helper reports scans written at most this often
_WAIT_S = 60.0  # an aborted helper gets this long to discard its files


def _send(stream, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)) + data)
    stream.flush()


def _receive(stream):
    """The next message, or None at the end of the stream (or a message cut short)."""
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    (n,) = _HEADER.unpack(head)
    data = stream.read(n)
    return pickle.loads(data) if len(data) == n else None


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _peak_rss_mb() -> float | None:
    try:
        import resource  # POSIX only
    except ImportError:
        return None
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)  # Linux: KiB


class Helper:
    """The parent's end: ``send`` the setup and poses, then ``finish`` (or ``abort``)."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc = proc
        self.written = 0  # scans the helper has written so far
        self._reply = None
        self._listener = threading.Thread(target=self._listen, daemon=True)
        self._listener.start()

    @classmethod
    def start(cls) -> Helper | None:
        """A helper process, or None on a single core or when none can be started (then the caller writes)."""
        if _cpus() < 2:
            return None
        root = str(Path(__file__).resolve().parents[2])  # this lio_cli, whatever the working directory holds
        code = f"import sys; sys.path.insert(0, {root!r}); from lio_cli.jobs.deskew_helper import main; main()"
        try:
            proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        except OSError:
            return None
        return cls(proc)

    def _listen(self) -> None:
        while True:
            msg = _receive(self.proc.stdout)
            if msg is None or msg[0] != "written":
                self._reply = msg
                return
            self.written = msg[1]

    def send(self, kind: str, value) -> None:
        """Send one message; when the helper has stopped, raise the error that stopped it."""
        try:
            _send(self.proc.stdin, (kind, value))
        except (BrokenPipeError, OSError):
            self._raise_reply()

    def _raise_reply(self):
        self._listener.join()
        self.proc.wait()
        reply = self._reply
        if reply is None or reply[0] != "error":
            raise ProcessingError(f"the writing process stopped without an answer (exit code {self.proc.returncode})")
        raise reply[1]

    def finish(self, level, progress=None) -> tuple[dict, object]:
        """Send the end and wait for the helper: (its statistics, its mounting); ``progress(written)`` meanwhile."""
        self.send("end", level)
        self.proc.stdin.close()
        while self._listener.is_alive():
            self._listener.join(_PROGRESS_S)
            if progress is not None:
                progress(self.written)
        self.proc.wait()
        if self._reply is None or self._reply[0] != "done":
            self._raise_reply()
        return self._reply[1]

    def abort(self) -> None:
        """Stop the helper without the end: it discards its files (killed if it does not within a minute)."""
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(_WAIT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


class _Aborted(Exception):
    """The parent's pipe closed without the end message."""


def main() -> None:
    """The helper process: read the setup and poses on stdin, write, answer on stdout."""
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # the answer's channel carries nothing else
    level = []
    try:
        from ..io.reader import open_log
        from .deskew_motion import settled_motion
        from .deskew_write import write_pass

        msg = _receive(inp)
        if msg is None:
            raise _Aborted
        job, fmt, plan, source, imu_topic, mounting, T_base_lidar = msg[1]

        def batches():
            while True:
                msg = _receive(inp)
                if msg is None:
                    raise _Aborted
                if msg[0] == "end":
                    level.append(msg[1])
                    return
                yield msg[1]

        last = [0.0]

        def progress(done: int, total) -> None:
            now = time.perf_counter()
            if now - last[0] >= _PROGRESS_S:
                last[0] = now
                _send(out, ("written", done))

        cfg = job.config
        with open_log(job.log, cfg.input.format) as reader:
            motion = settled_motion(job.log, cfg, source, imu_topic, mounting, T_base_lidar, batches())
            try:
                stats = write_pass(job, reader, fmt, plan, motion, progress, 0, None, lambda: level[0])
            finally:
                motion.close()
        stats["helper_peak_rss_mb"] = _peak_rss_mb()
        _send(out, ("done", (stats, mounting)))
        os._exit(0)  # every file is closed: skip the interpreter's teardown, which the parent would wait for
    except _Aborted:
        sys.exit(1)
    except BaseException as err:  # noqa: BLE001 - every failure goes back to the parent, which reports it
        if not isinstance(err, (LioError, KeyboardInterrupt)):
            traceback.print_exc()  # a bug: its traceback, as the parent would have printed it
        try:
            pickle.loads(pickle.dumps(err))
        except Exception:  # noqa: BLE001
            err = ProcessingError(f"the writing process failed: {type(err).__name__}: {err}")
        try:
            _send(out, ("error", err))
        except OSError:
            pass
        sys.exit(1)


__all__ = ["Helper", "main"]
