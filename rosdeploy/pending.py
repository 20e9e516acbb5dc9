"""Robots that have not converged yet: the controller's record, and when to try again.

A robot that was unreachable, busy (readiness gate) or waiting for its maintenance window
is *pending* for this fleet file and version. The record is one JSON file per fleet file
under $ROSDEPLOY_PENDING_DIR (default ~/.rosdeploy/pending/), written after every apply:

  - a robot that converged (deployed, unchanged) leaves it;
  - a robot that failed for another reason leaves it too (that failure is in the run log,
    and `apply` would only fail the same way);
  - an apply of another version supersedes every entry of the older one.

`status` shows the entries; a plain `apply` of the same fleet file and version takes the
pending robots along even when --limit leaves them out; `apply --until` retries them
with backoff and jitter (see delay).
"""
from __future__ import annotations

import hashlib
import json
import os
import random
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterable, Mapping

from rosdeploy import yamlsrc
from rosdeploy.errors import InputError
from rosdeploy.results import BUSY, UNREACHABLE, WAITING_WINDOW, HostResult

PENDING_OUTCOMES = frozenset({UNREACHABLE, BUSY, WAITING_WINDOW})
MAX_RECORD = 16 << 20     # bytes: a record of 20,000 robots is ~4 MB


@dataclass(frozen=True)
class Entry:
    host: str
    outcome: str          # unreachable | busy | waiting-window
    reason: str
    version: str
    since: str            # when it first became pending for this version (UTC, ISO)
    run: str              # the last run that tried it
    opens: str | None = None    # waiting-window: when the window opens

    def to_json(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}


def pending_dir() -> Path:
    return Path(os.environ.get("ROSDEPLOY_PENDING_DIR") or Path.home() / ".rosdeploy" / "pending")


def record_path(fleet_path: str) -> Path:
    """One record per fleet file (its absolute path, hashed: two fleets of one project differ)."""
    key = hashlib.sha256(os.path.abspath(fleet_path).encode()).hexdigest()[:16]
    return pending_dir() / f"{Path(fleet_path).stem}-{key}.json"


def load(fleet_path: str) -> dict[str, Entry]:
    return read(fleet_path)[0]


def read(fleet_path: str) -> tuple[dict[str, Entry], str | None]:
    """The record's entries, and what is wrong with it when it is not a record rosdeploy
    writes (edited, truncated, another tool's): such a record counts as none, and the next
    apply writes a good one over it."""
    path = record_path(fleet_path)
    if not path.exists():
        return {}, None
    try:   # bounded, regular files only: a fifo there would hang status
        data = json.loads(yamlsrc.read_bytes(str(path), MAX_RECORD, "a pending record").decode("utf-8"))
    except InputError as exc:
        return {}, f"{path}: {exc.problems[0].message}; ignored"
    except ValueError as exc:
        return {}, f"{path}: unreadable ({exc}); ignored"
    entries = _entries(data)
    if entries is None:
        return {}, f"{path}: not a pending record rosdeploy writes; ignored (the next apply replaces it)"
    return entries, None


_FIELDS = {"host": str, "outcome": str, "reason": str, "version": str, "since": str, "run": str}


def _entries(data: object) -> dict[str, Entry] | None:
    """The entries of a record as save() writes it; None when it is anything else."""
    hosts = data.get("hosts") if isinstance(data, dict) else None
    if not isinstance(hosts, dict):
        return None
    entries = {}
    for name, e in hosts.items():
        if not isinstance(e, dict) or set(e) - {"opens"} != set(_FIELDS):
            return None
        if not all(isinstance(e[k], kind) for k, kind in _FIELDS.items()) or not isinstance(e.get("opens", ""), str):
            return None
        entries[name] = Entry(**e)
    return entries


def for_version(entries: Mapping[str, Entry], version: str) -> dict[str, Entry]:
    return {h: e for h, e in entries.items() if e.version == version}


def merged(entries: Mapping[str, Entry], results: Iterable[HostResult], version: str, run_id: str,
           now: datetime | None = None) -> dict[str, Entry]:
    """The record after a run: older versions superseded, converged robots cleared."""
    stamp = (now or datetime.now(timezone.utc)).isoformat(timespec="seconds")
    out = dict(for_version(entries, version))
    for r in results:
        if r.outcome in PENDING_OUTCOMES:
            earlier = out.get(r.host)
            out[r.host] = Entry(r.host, r.outcome, r.reason, version, earlier.since if earlier else stamp,
                                run_id, r.opens)
        elif r.outcome != "skipped":          # converged, or failed for a reason retrying will not cure
            out.pop(r.host, None)
    return out


def save(fleet_path: str, entries: Mapping[str, Entry]) -> Path:
    """Write the record (temp file + rename: a concurrent `status` never reads half of it)."""
    path = record_path(fleet_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    doc = {"fleet": os.path.abspath(fleet_path), "hosts": {h: e.to_json() for h, e in sorted(entries.items())}}
    tmp.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    os.replace(tmp, path)
    return path


# ------------------------------------------------------------------- retrying

def delay(attempt: int, first: float, cap: float, rng: random.Random | None = None) -> float:
    """Seconds before retry number `attempt` (1, 2, ...): exponential from `first`, at most
    `cap`, with jitter in [half, all] of it so robots that dropped out together (one Wi-Fi
    access point) do not all come back in the same second."""
    base = min(cap, first * 2 ** max(0, attempt - 1))
    return (rng or random).uniform(base / 2, base)


def counts_as_failure(result: HostResult, count_busy: bool, retrying: bool) -> bool:
    """Against a wave's max_fail: real failures and unreachable robots, as before; never a
    robot waiting for its window; a busy one only when rollout.count_busy says so; an
    unreachable one not while `apply --until` will try it again."""
    if result.ok or result.outcome in ("skipped", WAITING_WINDOW):
        return False
    if result.outcome == BUSY:
        return count_busy
    return not (retrying and result.outcome == UNREACHABLE)


def next_try(result: HostResult, attempt: int, first: float, cap: float, now: float,
             wall: datetime | None = None, rng: random.Random | None = None) -> float:
    """When (on the monotonic clock `now` reads) to try a pending robot again: when its window
    opens (plus up to a second of jitter), else after delay(attempt)."""
    if result.outcome == WAITING_WINDOW and result.opens:
        wait = (datetime.fromisoformat(result.opens) - (wall or datetime.now(timezone.utc))).total_seconds()
        return now + max(0.0, wait) + (rng or random).uniform(0.0, 1.0)
    return now + delay(attempt, first, cap, rng)
