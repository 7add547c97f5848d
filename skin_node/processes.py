"""The package's console scripts as processes: how one runs, and how another
starts, waits for and stops it.

Running (``skin_node``, ``mocap_player``, ``skin_bag``): :func:`init_ros` and
:func:`build` take SIGINT/SIGTERM in two phases and turn a set-up failure into
one line and an exit code, :func:`spin_until_shutdown` spins until the context
shuts down, :class:`SpinThread` spins an executor in a thread of its own and
stops it in order. Starting one as a child (the ROS latency benchmark, the
integration tests, tools/stress.py): :func:`command`, :func:`wait_for_log`,
:func:`stop`.
"""
from __future__ import annotations

import contextlib
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.task import Future


def command(script: str, module: str) -> list[str]:
    """The console script ``script`` when it is on PATH (an install), else
    ``python -m module`` (a source tree)."""
    exe = shutil.which(script)
    return [exe] if exe else [sys.executable, "-m", module]


def wait_for_log(proc: subprocess.Popen, log: Path, text: str, timeout: float) -> None:
    """Wait until ``log`` (``proc``'s output) holds ``text``.

    Raises
    ------
    RuntimeError
        With the log's end, when ``proc`` ended or ``timeout`` seconds passed first.
    """
    deadline = time.monotonic() + timeout
    while text not in log.read_text():
        if proc.poll() is not None or time.monotonic() > deadline:
            state = f"exited {proc.returncode}" if proc.poll() is not None else "timed out"
            raise RuntimeError(f"{proc.args[0]} {state} before {text!r}:\n"
                               f"{log.read_text()[-3000:]}")
        time.sleep(0.2)


def stop(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout: float = 5.0) -> int:
    """Send ``sig`` to ``proc`` if it still runs and wait ``timeout`` seconds,
    then SIGKILL. Returns its exit status (negative: the signal that ended it)."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


_SETTING_UP = threading.Event()


def _on_signal(signum, frame) -> None:
    if _SETTING_UP.is_set():
        raise KeyboardInterrupt


def init_ros(args: list | None) -> None:
    """``rclpy.init`` with SIGINT and SIGTERM handled in two phases.

    rclpy's handlers shut the context down, which ends ``spin``, and then chain
    to the Python handler installed here. That one raises KeyboardInterrupt only
    inside :func:`setting_up` (long numpy/numba set-up never reaches ``spin``);
    afterwards it does nothing, so no interrupt can land in the middle of a
    clean shutdown.
    """
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)
    rclpy.init(args=args)


@contextlib.contextmanager
def setting_up():
    """Inside this block SIGINT/SIGTERM raise KeyboardInterrupt (see :func:`init_ros`)."""
    _SETTING_UP.set()
    try:
        yield
    finally:
        _SETTING_UP.clear()


def spin_until_shutdown(node: Node, future: Future | None = None) -> None:
    """Spin ``node`` until ``future`` is done or the context shuts down.

    A signal can shut the context down while rclpy builds its next wait set,
    which then raises instead of ExternalShutdownException: after a shutdown
    any such error is the normal way out, not a failure.
    """
    try:
        if future is None:
            rclpy.spin(node)
        else:
            rclpy.spin_until_future_complete(node, future)
    except ExternalShutdownException:
        pass
    except Exception:
        if node.context.ok():
            raise


class SpinThread:
    """An executor spinning in a thread of its own, stopped in order.

    For a tool whose main thread has other work (pacing a playback, feeding a
    benchmark). Such a thread must never outlive ``main``: at interpreter exit
    Python ends a still-running thread with ``pthread_exit`` when it next takes
    the GIL, and for one coming back from rclpy's wait the unwind crosses a
    ``noexcept`` C++ frame of rclpy, so ``std::terminate`` aborts the process
    ("terminate called without an active exception", SIGABRT) after all else
    went right. ``Executor.shutdown`` neither joins the thread nor (Jazzy)
    waits for a running callback. So :meth:`stop` ends the spin, joins the
    thread, and only then shuts the executor down; as a context manager, every
    way out of the block does that.

    Parameters
    ----------
    executor : rclpy.executors.Executor
        With its nodes added; this thread is the only one that spins it.
    name : str
        The thread's name.
    """

    def __init__(self, executor, name: str = "spin") -> None:
        self.executor = executor
        self._done = Future()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._spin, name=name)

    def _spin(self) -> None:
        try:
            self.executor.spin_until_future_complete(self._done)
        except ExternalShutdownException:
            pass                    # the context was shut down (a signal): the way out
        except BaseException as e:  # noqa: BLE001 - stop() raises it in the main thread
            if self.executor.context.ok():
                self._error = e

    def start(self) -> "SpinThread":
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop spinning once the running callback (if any) returns, join the
        thread, shut the executor down; then raise what a callback raised."""
        self._done.set_result(True)     # its done callback wakes the executor's wait
        if self._thread.ident is not None:
            self._thread.join()
        self.executor.shutdown()
        error, self._error = self._error, None
        if error is not None:
            raise error

    def __enter__(self) -> "SpinThread":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def build(name: str, factory):
    """Run ``factory()`` (a node's whole set-up) as a console script should.

    Returns ``(node, None)``, or ``(None, exit_code)``: 0 when SIGINT/SIGTERM
    arrived during set-up, 2 after printing one line ``<name>: error: ...``
    (never a bare traceback) for a bad parameter, file or any other failure.
    """
    try:
        with setting_up():
            return factory(), None
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return None, 0
    except (ValueError, OSError, ParameterException) as e:
        print(f"{name}: error: {e}", file=sys.stderr)
    except Exception as e:  # noqa: BLE001 - one line, not a traceback, for any set-up failure
        print(f"{name}: error: {type(e).__name__}: {e}", file=sys.stderr)
    rclpy.try_shutdown()
    return None, 2
