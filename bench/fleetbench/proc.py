"""Running and timing commands: argv lists only, wall time measured here."""
from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

REPO = Path(__file__).resolve().parents[2]


class BenchError(RuntimeError):
    """A setup step or a measured command did not do what the benchmark needs."""


@dataclass(frozen=True)
class Timed:
    argv: tuple[str, ...]
    code: int
    seconds: float
    stdout: str
    stderr: str
    cpu: float = 0.0     # user+sys seconds of the command and the children it waited for (the controller side)

    def tail(self, lines: int = 15) -> str:
        text = (self.stderr.strip() + "\n" + self.stdout.strip()).strip()
        return "\n".join(text.splitlines()[-lines:])


def timed(argv: Sequence[str], *, env: Mapping[str, str] | None = None, cwd: Path | None = None,
          timeout: float = 900.0) -> Timed:
    """Run argv to completion and measure its wall time (process start included)."""
    full_env = {**os.environ, **env} if env else None
    before = _children_cpu()
    started = time.monotonic()
    try:
        proc = subprocess.run(list(argv), capture_output=True, text=True, env=full_env, cwd=cwd,
                              timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as exc:
        raise BenchError(f"`{' '.join(argv[:4])} ...` took longer than {timeout:.0f} s") from exc
    seconds = time.monotonic() - started
    return Timed(tuple(argv), proc.returncode, seconds, proc.stdout, proc.stderr, _children_cpu() - before)


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def check(argv: Sequence[str], *, what: str, env: Mapping[str, str] | None = None,
          timeout: float = 600.0) -> Timed:
    """Run a setup command; BenchError with its output when it fails."""
    result = timed(argv, env=env, timeout=timeout)
    if result.code != 0:
        raise BenchError(f"{what} failed (exit {result.code}):\n{result.tail()}")
    return result


def expect(result: Timed, codes: Sequence[int], what: str) -> Timed:
    """A measured command must end the way the scenario expects, else its time means nothing."""
    if result.code not in codes:
        raise BenchError(f"{what}: exit {result.code}, expected {' or '.join(map(str, codes))}:\n"
                         f"{result.tail()}")
    return result


def rosdeploy_argv(*args: str) -> list[str]:
    """The rosdeploy CLI as a user runs it (a fresh interpreter each time)."""
    return [sys.executable, "-m", "rosdeploy", *args]


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)
