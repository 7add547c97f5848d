"""A pipeline in a process of its own, fed through shared memory.

A :class:`RemotePipeline` answers like a :class:`~skin_node.Pipeline`
(``deform``, ``timings``, ``counts``, ``params``, ``stage_names``,
``set_params``), but the character is set up and deformed in a child process
(``python -m skin_node.remote``). The pose goes in and the skin comes out
through one shared memory block; a socket pair carries the few bytes that say
"deform now" and "done, these were the stage times". So whatever runs in the
calling process (rclpy's executor, DDS callbacks, message packing) never
holds the GIL the deform needs, and the deform never holds theirs.

The child runs the same code on the same character: its skin is bitwise the
calling process's (``test/test_remote.py``). It exits when the calling
process closes the pipeline or dies (its end of the socket closes), ignores
SIGINT (a terminal's Ctrl-C reaches the whole process group; the parent
stops it in order), and a child that dies mid-frame is started again on the
next pose (:attr:`RemotePipeline.restarts`).

Linux gives the block as a ``memfd`` (no name to leak when a process is
killed); elsewhere it is an unlinked temporary file.
"""
from __future__ import annotations

import argparse
import mmap
import os
import signal
import socket
import subprocess
import sys
import tempfile
from multiprocessing.connection import Connection

import numpy as np

#: Seconds a child may take to load the character, build and warm up its
#: pipeline (a first start compiles every kernel: about a minute here).
READY_TIMEOUT_S = 900.0


def _shared_block(size: int):
    """A file descriptor of ``size`` bytes another process can map."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("skin_node", 0)
    else:                                   # pragma: no cover - not Linux
        f = tempfile.TemporaryFile()
        fd = os.dup(f.fileno())
        f.close()
    os.ftruncate(fd, size)
    return fd


def _views(mm, n_channels: int, n_out: int):
    """The pose (C,) and the skin (n, 3) in the block, float64."""
    q = np.frombuffer(mm, dtype=np.float64, count=n_channels, offset=0)
    V = np.frombuffer(mm, dtype=np.float64, count=3 * n_out,
                      offset=8 * n_channels).reshape(n_out, 3)
    return q, V


class RemoteError(RuntimeError):
    """The child failed a request, or died."""


class RemotePipeline:
    """A :class:`~skin_node.Pipeline` of ``character`` deformed in a child process.

    Parameters
    ----------
    character : Character
        Set up in this process already: its shape sizes the block; the child
        loads the same one (from the on-disk cache) with ``load``.
    load : dict
        :func:`~skin_node.load_character`'s arguments (``spec``,
        ``surface_vertices``, ``weights``) for the child.
    stages, params
        As :class:`~skin_node.Pipeline`'s (checked there, in the child).
    wait : bool
        Wait here until the child is ready; with False, :meth:`wait_ready`
        does (several children then set up at once).
    """

    def __init__(self, character, load: dict, stages, wait: bool = True, **params) -> None:
        self._load = dict(load)
        self.stage_names = list(stages)
        self.params: dict = dict(params)
        self.timings: dict = {}
        self.counts: dict = {}
        self.restarts = 0
        self.warm_s = 0.0
        self._n_channels = character.skeleton.n_channels
        self._n_out = len(character.surface_V)
        self._proc: subprocess.Popen | None = None
        self._conn: Connection | None = None
        size = 8 * (self._n_channels + 3 * self._n_out)
        self._fd = _shared_block(size)
        self._mm = mmap.mmap(self._fd, size)
        self._q, self._V = _views(self._mm, self._n_channels, self._n_out)
        self._ready = False
        self._start()
        if wait:
            self.wait_ready()

    # ------------------------------------------------------------ the child
    def _start(self) -> None:
        """Start the child and ask it to set up (:meth:`wait_ready` waits for it)."""
        mine, theirs = socket.socketpair()
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "skin_node.remote", "--socket", str(theirs.fileno()),
             "--block", str(self._fd)],
            pass_fds=(theirs.fileno(), self._fd), env=env, stdin=subprocess.DEVNULL)
        theirs.close()
        self._conn = Connection(mine.detach())
        self._conn.send(("setup", self._load, self.stage_names, self.params,
                         self._n_channels, self._n_out))
        self._ready = False

    def wait_ready(self) -> float:
        """Wait until the child has set up and warmed up its pipeline; returns
        the warm-up's seconds (RemoteError, or ValueError for a bad request,
        when it could not)."""
        if not self._ready:
            try:
                self.warm_s = float(self._reply(READY_TIMEOUT_S, "set-up"))
            except (ValueError, RemoteError):
                self._discard()
                raise
            self._ready = True
        return self.warm_s

    def _ask(self, message: tuple, timeout: float | None, what: str):
        """Send ``message`` and return the child's answer (:meth:`_reply`).
        A child already dead fails the send or the read, whichever comes first
        after it died: both are the same RemoteError."""
        try:
            self._conn.send(message)
        except OSError:
            raise self._gone(what) from None
        return self._reply(timeout, what)

    def _gone(self, what: str) -> RemoteError:
        """The error of a child that died (it is forgotten: the next request
        starts another)."""
        try:
            code = self._proc.wait(5.0)
        except subprocess.TimeoutExpired:
            code = None
        self._discard()
        return RemoteError(f"{what}: the deform process exited (status {code})")

    def _reply(self, timeout: float | None, what: str):
        """The child's answer to the last request; RemoteError when it
        failed it, died, or gave no answer in ``timeout`` seconds (then it is
        stopped: a late answer must not pass for the next one's)."""
        try:
            if timeout is not None and not self._conn.poll(timeout):
                self._discard()
                raise RemoteError(f"{what}: no answer from the deform process in "
                                  f"{timeout:.0f} s; stopped it")
            kind, value = self._conn.recv()
        except (EOFError, OSError):
            raise self._gone(what) from None
        if kind == "invalid":           # the child's ValueError: the request was wrong
            raise ValueError(value)
        if kind == "fail":
            raise RemoteError(f"{what}: {value}")
        return value

    def _discard(self) -> None:
        """Forget a child that is gone (or is being stopped)."""
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if self._proc is not None:
            if self._proc.poll() is None:
                self._proc.kill()
            self._proc.wait()
            self._proc = None

    @property
    def pid(self) -> int | None:
        """The child's process id (None while it is not running)."""
        return self._proc.pid if self._proc is not None else None

    # ------------------------------------------------------------ the pipeline
    def deform(self, q: np.ndarray) -> np.ndarray:
        """:meth:`skin_node.Pipeline.deform` in the child: (n, 3) float64, a new array.

        Raises
        ------
        ValueError
            A pose the pipeline refuses (wrong shape, NaN), as it says.
        RemoteError
            The child failed the frame (its message), or died in it; a child
            that died is started again by the next call.
        """
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self._n_channels,):
            raise ValueError(f"pose has shape {q.shape}, expected ({self._n_channels},)")
        self._restart()
        self._q[:] = q
        self.timings, self.counts = self._ask(("deform",), None, "deform")
        return self._V.copy()

    def set_params(self, **params) -> None:
        """Apply parameters in the child (checked there; ValueError as
        :meth:`skin_node.Pipeline.set_params` raises it)."""
        self._request(("params", params), "parameters")
        self.params.update(params)

    def set_stages(self, stages, **params) -> float:
        """Rebuild the child's pipeline with ``stages`` and ``params`` and warm
        it up (the kernels of new stages compile or load there, not in a real
        frame). Returns the warm-up's seconds."""
        s = self._request(("stages", list(stages), params), "stages")
        self.stage_names, self.params = list(stages), dict(params)
        return float(s)

    def warm_up(self) -> float:
        """The child warmed up before it said it was ready: its seconds."""
        return self.warm_s

    def _restart(self) -> None:
        """Start a child again where the last one died."""
        if self._conn is None:
            self.restarts += 1
            self._start()
        self.wait_ready()

    def _request(self, message: tuple, what: str):
        self._restart()
        return self._ask(message, READY_TIMEOUT_S, what)

    def close(self, timeout: float = 5.0) -> None:
        """Stop the child (it finishes the request it is on) and free the block."""
        if self._conn is not None:
            try:
                self._conn.send(("stop",))
            except OSError:
                pass
            try:
                self._proc.wait(timeout)
            except subprocess.TimeoutExpired:
                pass
            self._discard()
        if self._mm is not None:
            self._q = self._V = None
            self._mm.close()
            os.close(self._fd)
            self._mm = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close(1.0)
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


def _describe(e: BaseException) -> str:
    return f"{type(e).__name__}: {e}"


def serve(conn: Connection, block_fd: int) -> int:
    """The child's loop: set up, then answer requests until ``stop`` or EOF."""
    # deferred: the parent may import this module without the core's set-up cost
    from .character import load_character
    from .pipeline import Pipeline

    try:
        _, load, stages, params, n_channels, n_out = conn.recv()
    except EOFError:
        return 0
    mm = mmap.mmap(block_fd, 8 * (n_channels + 3 * n_out))
    q, V = _views(mm, n_channels, n_out)
    try:
        spec = load.pop("spec")
        character = load_character(spec, progress=False, **load)
        if character.skeleton.n_channels != n_channels or len(character.surface_V) != n_out:
            raise ValueError(f"{spec} set up with {character.skeleton.n_channels} channels and "
                             f"{len(character.surface_V)} vertices here, {n_channels} and "
                             f"{n_out} in the calling process")
        pipe = Pipeline(character, stages=stages, **params)
        warm = pipe.warm_up()
    except ValueError as e:
        conn.send(("invalid", str(e)))
        return 1
    except Exception as e:  # noqa: BLE001 - the parent reports it
        conn.send(("fail", _describe(e)))
        return 1
    conn.send(("ok", warm))
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return 0                        # the calling process is gone
        kind = request[0]
        if kind == "stop":
            return 0
        try:
            if kind == "deform":
                V[:] = pipe.deform(q)
                reply = (pipe.timings, pipe.counts)
            elif kind == "params":
                pipe.set_params(**request[1])
                reply = None
            elif kind == "stages":
                new = Pipeline(character, stages=request[1], **request[2])
                reply = new.warm_up()
                pipe = new
            else:
                raise ValueError(f"unknown request {kind!r}")
        except ValueError as e:
            conn.send(("invalid", str(e)))
            continue
        except Exception as e:  # noqa: BLE001 - a bad frame must not stop the child
            conn.send(("fail", _describe(e)))
            continue
        conn.send(("ok", reply))


def main(argv: list | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m skin_node.remote",
                                 description="the deform process of a RemotePipeline "
                                             "(started by it, not by hand)")
    ap.add_argument("--socket", type=int, required=True, help="inherited socket descriptor")
    ap.add_argument("--block", type=int, required=True, help="inherited shared memory descriptor")
    a = ap.parse_args(argv)
    # Ctrl-C in a terminal signals the whole group: the parent stops this one in order
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn = Connection(socket.socket(fileno=a.socket).detach())
    try:
        return serve(conn, a.block)
    finally:
        conn.close()


if __name__ == "__main__":
    sys.exit(main())
