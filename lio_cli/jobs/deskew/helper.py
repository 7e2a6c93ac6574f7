"""The writing pass of ``lio deskew`` in a second process, beside the odometry: on two cores a run takes about
as long as its odometry alone, not the odometry plus the writing.

The parent starts the helper (``Helper.start``) before its odometry and sends it the setup, then each batch
of settled poses as the odometry settles them, then the rotation that levels the odometry's world frame.
The helper reads the log itself, writes the output log and the map to temporary siblings (it names them to
the parent as it makes them) and answers "ready" with the pass's statistics, or with the error that stopped
it; only on the parent's "commit" does it rename them into place. When the parent's end of the pipe closes
before that (its odometry failed, or it was interrupted) the helper discards what it wrote; a helper that
cannot (killed) leaves that to the parent. The helper's progress (scans written) comes back on the pipe too.

Messages are pickles behind a length prefix: the parent's on the helper's stdin, the helper's on its stdout
(a duplicate of it: the helper's fd 1 itself, and anything printed there, goes to stderr).
"""

from __future__ import annotations

import os
import pickle
import queue
import signal
import struct
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

from ...cpus import usable_cpus
from ...errors import LioError, ProcessingError
from ...io.files.atomic import remove_path

_HEADER = struct.Struct("<Q")
_PROGRESS_S = 0.1  # the helper reports scans written at most this often
_WAIT_S = 60.0  # an aborted helper gets this long to discard its files
_PARENT_POLL_S = 0.5  # how often the helper checks that its parent lives


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
        self.temps: list[Path] = []  # the helper's temporary outputs, removed here if it cannot remove them
        self._replies: queue.Queue = queue.Queue()  # its answers; None when its stdout closed
        self._listener = threading.Thread(target=self._listen, daemon=True)
        self._listener.start()

    @classmethod
    def start(cls) -> Helper | None:
        """A helper process, or None on a single core or when none can be started (then the caller writes)."""
        if usable_cpus() < 2:
            return None
        root = str(Path(__file__).resolve().parents[3])  # this lio_cli, whatever the working directory holds
        code = f"import sys; sys.path.insert(0, {root!r}); from lio_cli.jobs.deskew.helper import main; main()"
        try:
            # its own session: a Ctrl-C to the terminal's process group is the parent's to handle (it aborts the
            # helper), never a traceback from the helper's start-up
            proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    start_new_session=True)
        except OSError:
            return None
        return cls(proc)

    def _listen(self) -> None:
        try:
            while True:
                msg = _receive(self.proc.stdout)
                if msg is None:
                    return
                if msg[0] == "written":
                    self.written = msg[1]
                elif msg[0] == "temp":
                    self.temps.append(Path(msg[1]))
                else:
                    self._replies.put(msg)
        finally:  # the end of its answers, however the stream ended
            self._replies.put(None)

    def send(self, kind: str, value) -> None:
        """Send one message; when the helper has stopped, raise the error that stopped it."""
        try:
            _send(self.proc.stdin, (kind, value))
        except (BrokenPipeError, OSError):
            self._fail(self._replies.get())

    def _fail(self, reply):
        """Raise the helper's error (or that it stopped without one), once it has exited and left nothing."""
        self.abort()
        if reply is None or reply[0] != "error":
            raise ProcessingError(f"the writing process stopped without an answer (exit code {self.proc.returncode})")
        raise reply[1]

    def _expect(self, kind: str, progress=None):
        while True:
            try:
                reply = self._replies.get(timeout=_PROGRESS_S)
            except queue.Empty:
                if progress is not None:
                    progress(self.written)
                continue
            if reply is None or reply[0] != kind:
                self._fail(reply)
            return reply[1]

    def finish(self, level, progress=None) -> tuple[dict, object]:
        """Send the end, wait for the helper's last scans, then let it rename its outputs into place: (its
        statistics, its mounting); ``progress(written)`` meanwhile. Interrupted before the rename, the helper
        discards them."""
        try:
            self.send("end", level)
            ready = self._expect("ready", progress)
            self.send("commit", None)
            self._expect("committed")
        except BaseException:
            self.abort()
            raise
        self.proc.stdin.close()
        self.proc.wait()
        return ready

    def abort(self) -> None:
        """Stop the helper without the end: it discards its files (killed if it does not within a minute, and
        its temporaries then removed here)."""
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        if self.proc.poll() is None:
            self.proc.terminate()  # it may be writing scans and not reading its pipe: discard now
        try:
            self.proc.wait(_WAIT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._listener.join()
        for tmp in self.temps:
            remove_path(tmp)


class _Aborted(BaseException):
    """The parent's pipe closed without the end (or the commit) message, or it ended the helper (SIGTERM)."""


def _ignore(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    """A later signal while the helper discards its files: they are discarded all the same."""


def _terminated(signum, frame):  # noqa: ARG001 - signal handler signature
    signal.signal(signal.SIGTERM, _ignore)
    signal.signal(signal.SIGINT, _ignore)
    raise _Aborted


def _watch_parent(parent: int) -> None:
    """End the helper (as the parent's SIGTERM would) when its parent has died (killed: it cannot abort it)."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(_PARENT_POLL_S)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, daemon=True).start()


def main() -> None:
    """The helper process: read the setup and poses on stdin, write, answer on stdout."""
    signal.signal(signal.SIGTERM, _terminated)
    signal.signal(signal.SIGINT, _terminated)
    _watch_parent(os.getppid())
    inp = sys.stdin.buffer
    out = os.fdopen(os.dup(1), "wb")  # the answers' channel; anything else written to fd 1 goes to stderr
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    level = []

    def answer(msg) -> None:
        try:
            _send(out, msg)
        except OSError as err:  # the parent is gone (killed): nobody to answer, discard quietly
            raise _Aborted from err

    try:
        from ...io.logs.reader import open_log
        from .write import write_pass

        msg = _receive(inp)
        if msg is None:
            raise _Aborted
        setup = msg[1]  # deskew_write.WriteSetup
        job = setup.job

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
                answer(("written", done))

        def commit(stats: dict) -> None:
            stats["helper_peak_rss_mb"] = _peak_rss_mb()
            answer(("ready", (stats, setup.mounting)))
            msg = _receive(inp)
            if msg is None or msg[0] != "commit":
                raise _Aborted

        cfg = job.config
        with open_log(job.log, cfg.input.format) as reader:
            motion = setup.motion(batches())
            try:
                write_pass(job, reader, setup.fmt, setup.plan, motion, progress, 0, None, lambda: level[0],
                           on_temp=lambda path: answer(("temp", str(path))), before_commit=commit)
            finally:
                motion.close()
        answer(("committed", None))
        os._exit(0)  # every file is closed: skip the interpreter's teardown, which the parent would wait for
    except _Aborted:  # its files are discarded: leave at once (a SIGTERM meeting the teardown would kill it)
        sys.stderr.flush()
        os._exit(1)
    except BaseException as err:  # noqa: BLE001 - every failure goes back to the parent, which reports it
        # its files are discarded; the parent ends it (SIGTERM) once it has the error, maybe while it still
        # answers: end quietly then (an _Aborted raised here printed a traceback under the error line)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, _ignore)
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
