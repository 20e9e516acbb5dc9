"""Running host commands for the simulator: argv lists only, failures become SimError.

Long steps (debootstrap, image builds, pushes) write their output to a log file
and report "still running" through the progress callback, so a user sees the
simulator is alive without the library printing anything.
"""
from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path
from typing import IO, Callable, Mapping, Sequence

from rosdeploy.errors import SimError

Progress = Callable[[str], None]

HEARTBEAT_S = 20.0
HOST_SETUP_HINT = "run `sudo bash scripts/host-setup` in the rosdeploy checkout"


def quiet(_message: str) -> None:
    """The default progress callback: library code never prints."""


def run(argv: Sequence[str], *, what: str, check: bool = True, input: str | None = None,
        stdin: IO[bytes] | None = None, timeout: float | None = 300) -> subprocess.CompletedProcess[str]:
    """Run a short command and capture its output; raise SimError saying what failed."""
    try:
        result = subprocess.run(list(argv), capture_output=True, text=True, input=input, stdin=stdin,
                                timeout=timeout)
    except FileNotFoundError as exc:
        raise SimError(f"{what}: `{argv[0]}` is not installed ({HOST_SETUP_HINT})") from exc
    except subprocess.TimeoutExpired as exc:
        raise SimError(f"{what}: `{' '.join(argv[:3])}` took longer than {timeout:.0f} s") from exc
    if check and result.returncode != 0:
        raise SimError(f"{what} failed (exit {result.returncode}): {tail(result.stderr or result.stdout)}")
    return result


def run_logged(argv: Sequence[str], *, what: str, log: Path, progress: Progress,
               timeout: float = 1800, env: Mapping[str, str] | None = None) -> float:
    """Run a long command with its output in `log`; return its wall time in seconds."""
    log.parent.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    with log.open("w") as sink:
        try:
            proc = subprocess.Popen(list(argv), stdout=sink, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL,
                                    env={**os.environ, **env} if env else None)
        except FileNotFoundError as exc:
            raise SimError(f"{what}: `{argv[0]}` is not installed ({HOST_SETUP_HINT})") from exc
        code = _wait_with_heartbeat(proc, what, started, timeout, progress)
    if code != 0:
        raise SimError(f"{what} failed (exit {code}); see {log}:\n{tail(log.read_text(errors='replace'))}")
    return time.monotonic() - started


def _wait_with_heartbeat(proc: subprocess.Popen, what: str, started: float, timeout: float,
                         progress: Progress) -> int:
    next_beat = started + HEARTBEAT_S
    while True:
        try:
            return proc.wait(timeout=max(0.1, next_beat - time.monotonic()))
        except subprocess.TimeoutExpired:
            elapsed = time.monotonic() - started
            if elapsed > timeout:
                proc.kill()
                proc.wait()
                raise SimError(f"{what} took longer than {timeout:.0f} s and was stopped") from None
            progress(f"{what}: still running ({elapsed:.0f} s)")
            next_beat += HEARTBEAT_S


def tail(text: str, lines: int = 8) -> str:
    return "\n".join(text.strip().splitlines()[-lines:])


def docker(*args: str, what: str, check: bool = True, input: str | None = None,
           timeout: float | None = 300) -> subprocess.CompletedProcess[str]:
    return run(("docker", *args), what=what, check=check, input=input, timeout=timeout)


def _docker_info() -> subprocess.CompletedProcess[str]:
    return run(("docker", "info", "--format", "{{.ServerVersion}}"), what="docker info", check=False, timeout=30)


def engine_up() -> bool:
    return _docker_info().returncode == 0


def require_engine() -> None:
    """Fail early, and say how to fix it, when no Docker engine answers."""
    result = _docker_info()
    if result.returncode != 0:
        raise SimError("no Docker engine answers (`docker info`: "
                       f"{tail(result.stderr, 2) or 'no output'}); {HOST_SETUP_HINT}, "
                       "which installs docker.io and starts dockerd, then retry")
