"""The package's console scripts as child processes: start, wait for, stop.

For what runs ``skin_node``, ``skin_bag`` or ``mocap_player`` as processes of
their own: the ROS latency benchmark, the integration tests, tools/stress.py.
"""
from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path


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
