"""The deploy guard: what ends a deploy on the robot when its controller cannot.

While a deploy is in flight (from the lock to the activation), a small container
runs on the robot: `rosdeploy-guard-<project>`, restart policy `always`, no compose
labels, running GUARD_SCRIPT with the robot's own tools (`chroot /host`, as the
deploying user). dockerd starts it again after a reboot, so it acts at boot as well.
It holds a deadline; when the deadline passes without activation, or it finds it was
started again (the robot restarted), it ends the deploy by itself:

    revert   start the last activated release (`current`) again, the way the brake does
    finish   run the release's own gate on the robot; activate it if it passes, else revert

It appends a `guard-rollback` / `guard-finish` history entry with the reason, releases
the lock of the run that armed it, and removes its own container. The controller
disarms it by removing the state file (activation, or the run's own end): the guard
sees that within a second and removes itself. See docs/guard.md.

A rollback (`rosdeploy rollback`, the fleet's rollback) arms one too, mode ROLLBACK, in its
lock+state round trip; the `up` that switches re-arms it with the target. At its deadline
(rollback_deadline) or after a reboot it completes the rollback: the target started the
brake's way, activated, `guard-finished-rollback`.

This module holds the script, the state file's format and the pure decisions made
from it; commands.py builds the commands that arm and disarm it.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

MODES = ("revert", "finish", "off")
ROLLBACK = "rollback"  # the state's mode while an operator's (or the fleet's) rollback is in flight
STATE = "state"        # armed, waiting for its deadline
ACTING = "acting"      # the state, renamed when the guard took over


@dataclass(frozen=True)
class Guard:
    """A guard as its state file on the robot tells it."""

    run: str
    by: str
    mode: str                   # revert | finish | rollback
    phase: str                  # prepare (lock to upload) | start (a container of `target` may run)
    target: str
    previous: str | None        # `current` when it was armed
    deadline: int | None        # robot's clock, seconds since the epoch
    boot: str = ""
    acting: bool = False
    reason: str = ""            # why it acts (acting only)
    gated: bool = True          # rollback: its target passed a gate here before

    @property
    def kind(self) -> str:
        """What it guards, for people: a deploy or a rollback."""
        return "rollback" if self.mode == ROLLBACK else "deploy"

    def seconds_left(self, clock: int | None) -> int | None:
        if self.deadline is None or clock is None:
            return None
        return max(0, self.deadline - clock)

    @property
    def will(self) -> str:
        """What it does when it acts: a verb phrase for people."""
        if self.phase == "prepare":
            return "releases the lock"
        if self.mode == ROLLBACK:
            return f"finishes the rollback to {self.target}" if self.gated else f"reverts to {self.previous}"
        if self.mode == "finish":
            return f"gates {self.target} itself"
        return f"reverts to {self.previous}" if self.previous else f"stops {self.target}"


# A number the robot sends (a clock, a deadline, free space): ASCII digits only (str.isdigit()
# takes "²", which int() refuses), and few enough for any real value (int() refuses 5,000).
_DIGITS = re.compile(r"[0-9]{1,18}")


def digits(text: str | None) -> int | None:
    """A whole number from the robot; None for anything else."""
    text = (text or "").strip()
    return int(text) if _DIGITS.fullmatch(text) else None


def parse_guard(text: str | None, acting: bool = False) -> Guard | None:
    """The state file: `key=value` lines; a later line wins (a re-arm appends)."""
    if not text or not text.strip():
        return None
    values: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, value = line.partition("=")
        if sep:
            values[key.strip()] = value
    if not values.get("run"):
        return None
    return Guard(run=values["run"], by=values.get("by", ""), mode=values.get("mode", "revert"),
                 phase=values.get("phase", "prepare"), target=values.get("target", ""),
                 previous=values.get("previous") or None,
                 deadline=digits(values.get("deadline")), boot=values.get("boot", ""),
                 acting=acting, reason=values.get("reason", ""), gated=values.get("gated", "yes") == "yes")


def state_text(fields: Mapping[str, object]) -> str:
    """The state the controller arms with (the robot adds dir, phase, deadline, boot).
    One value per line: a newline inside a value would start a key of its own."""
    return "".join(f"{k}={' '.join(str(v).split()) if k != 'services' else v}\n" for k, v in fields.items())


def rollback_deadline(command_timeout: float, gate: float, margin: float) -> float:
    """Seconds from a rollback's `up` until its guard completes it. The controller may wait for
    the `up` (ssh.command_timeout) and then, counted from the same start, for the target's
    health (health.timeout) before it activates: a shorter deadline would race a live one."""
    return max(command_timeout, gate) + margin


def rearm_text(run: str, seconds: float, fields: Mapping[str, object]) -> str:
    """A re-arm that also brings state lines ("RUN SECONDS" + lines; see `rearm` in _guard.sh)."""
    return f"{run} {int(seconds)}\n{state_text(fields)}"


def probe_spec(topics: list[dict], window: float, within: float) -> str:
    """The controller's probe, as the guard runs it (`finish` mode): a topic counts once it has a publisher."""
    spec = {"topics": topics, "discovery_timeout": within, "window": window, "published": True}
    return json.dumps(spec, sort_keys=True)


# The guard itself: a fixed script shipped with the package, checked by shellcheck.
GUARD_SCRIPT = (Path(__file__).parent / "guard.sh").read_text(encoding="utf-8")
