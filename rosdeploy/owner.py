"""Who holds a robot's lock, and whether that run is certainly gone.

A run that dies without unlocking (kill -9, a crash, a closed laptop lid) leaves its
lock on the robot. Only the system that ran it can prove it dead: the same running
kernel (boot id: random per boot, so no other machine has it) and the same pid
namespace (a container sees other pids), and no process with the run's pid. Anything
less certain keeps the lock, and the operator decides with --break-lock: another
machine, a reboot since (a cloned machine looks just like that), a live pid (perhaps
reused, but perhaps not), a record without these fields.
"""
from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from dataclasses import dataclass
from typing import Callable, Mapping

BOOT_ID_FILE = "/proc/sys/kernel/random/boot_id"
PID_NAMESPACE = "/proc/self/ns/pid"


@dataclass(frozen=True)
class Controller:
    """This system as a lock names it; None where it cannot tell."""
    boot: str | None
    pid_namespace: str | None


def this_controller() -> Controller:
    try:
        with open(BOOT_ID_FILE, encoding="ascii") as f:
            boot: str | None = f.readline().strip() or None
    except (OSError, UnicodeDecodeError):
        boot = None
    try:
        namespace: str | None = os.readlink(PID_NAMESPACE)     # "pid:[4026531836]"
    except OSError:
        namespace = None
    return Controller(boot=boot, pid_namespace=namespace)


def pid_alive(pid: int) -> bool:
    """A process with this pid exists (ours or another user's)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass          # it exists, under another user
    return True


def record(run: str, by: str, since: str, here: Controller, pid: int) -> dict:
    """What a lock holds: who took it, and what proves later whether that run still lives."""
    return {"run": run, "by": by, "since": since, "pid": pid, "boot": here.boot, "pid_namespace": here.pid_namespace}


def dead_run(holder: str, here: Controller, alive: Callable[[int], bool] | None = None) -> tuple[str, str] | None:
    """(run id, why it is dead) for a lock left by a run of this system that no longer
    runs; None when that cannot be proven. `holder`: the lock's owner record (JSON);
    `alive`: how to look a pid up (default: this system's processes)."""
    try:
        owner = json.loads(holder)
    except ValueError:
        return None
    if not isinstance(owner, Mapping):
        return None
    run, pid = owner.get("run"), owner.get("pid")
    if not isinstance(run, str) or not run or type(pid) is not int or pid <= 0:
        return None
    if not here.boot or not here.pid_namespace:
        return None
    if owner.get("boot") != here.boot or owner.get("pid_namespace") != here.pid_namespace:
        return None
    if (alive or pid_alive)(pid):
        return None
    return run, f"its process {pid} on this machine is gone"


def holder_alive(owner: Mapping | None, here: Controller, alive: Callable[[int], bool] | None = None) -> bool | None:
    """Is the run holding a lock still running? True/False when its record says it ran on this
    system (same boot, same pid namespace); None when this system cannot tell."""
    if not isinstance(owner, Mapping):
        return None
    pid = owner.get("pid")
    if type(pid) is not int or pid <= 0 or not here.boot or not here.pid_namespace:
        return None
    if owner.get("boot") != here.boot or owner.get("pid_namespace") != here.pid_namespace:
        return None
    return (alive or pid_alive)(pid)


def describe(holder: str | Mapping | None) -> str:
    """A lock's owner for people: `root@host (run …, pid …, since …)`; the raw text when it
    is not an owner record."""
    owner = holder
    if isinstance(holder, str):
        try:
            owner = json.loads(holder)
        except ValueError:
            return holder.strip() or "an unknown run"
    if not isinstance(owner, Mapping):
        return str(holder)
    # A record is any JSON a robot holds: a field of the wrong type is left out, never printed raw
    # (`locked by {'user': 'alice'}`).
    by = owner.get("by")
    fields = {"run": _text(owner.get("run")), "pid": _number(owner.get("pid")), "since": _time(owner.get("since"))}
    details = [f"{k} {v}" for k, v in fields.items() if v]
    return (by if isinstance(by, str) and by.strip() else "an unknown user") + \
        (f" ({', '.join(details)})" if details else "")


def _text(value: object) -> str:
    return value if isinstance(value, str) else ""


def _number(value: object) -> str:
    return str(value) if type(value) is int else ""


def _time(value: object) -> str:
    """An ISO time as written; an epoch (seconds) as ISO time in UTC."""
    if type(value) in (int, float):
        try:
            return datetime.fromtimestamp(value, timezone.utc).isoformat(timespec="seconds")  # type: ignore[arg-type]
        except (OverflowError, OSError, ValueError):
            return ""
    return _text(value)
