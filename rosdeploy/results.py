"""Outcomes: what happened on each robot, kept whole for the summary, --json and the run log."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Mapping

# Outcomes of one robot. The first three are success.
UNCHANGED = "unchanged"        # already on the release and healthy: nothing done
DEPLOYED = "deployed"          # new release running, healthy, `current`
SWITCHED = "switched"          # emergency rollback: now on the older release, healthy
ROLLED_BACK = "rolled-back"    # new release failed its health gate; previous one restored
FAILED = "failed"              # nothing switched (preflight, pull, lock...) or recovery failed
STOPPED = "stopped"            # new release failed and there was no previous one: stopped
UNREACHABLE = "unreachable"    # SSH failed: host key, network, auth
LOCKED = "locked"              # another run holds the robot's lock
SKIPPED = "skipped"            # not started: rollout stopped or interrupted first
BUSY = "busy"                  # readiness gate still failing at ready.max_wait: images pulled, nothing restarted
WAITING_WINDOW = "waiting-window"   # outside its maintenance window: images pulled, nothing restarted
OK_OUTCOMES = frozenset({UNCHANGED, DEPLOYED, SWITCHED})
OUTCOMES = OK_OUTCOMES | {ROLLED_BACK, FAILED, STOPPED, UNREACHABLE, LOCKED, SKIPPED, BUSY, WAITING_WINDOW}


@dataclass(frozen=True)
class Step:
    name: str
    seconds: float
    ok: bool = True
    detail: str = ""


@dataclass(frozen=True)
class HostResult:
    host: str
    outcome: str
    old_release: str | None = None
    new_release: str | None = None
    running_release: str | None = None     # what runs on the robot now, as far as we know
    reason: str = ""
    failed_service: str | None = None
    logs: Mapping[str, str] = field(default_factory=dict)   # service -> last log lines
    steps: tuple[Step, ...] = ()
    seconds: float = 0.0
    wave: int | None = None
    opens: str | None = None                # waiting-window: when the window opens (UTC, ISO)
    earlier: tuple[str, ...] = ()           # `apply --until`: "outcome: reason" of this run's earlier tries

    @property
    def ok(self) -> bool:
        return self.outcome in OK_OUTCOMES

    @property
    def version(self) -> str | None:
        return version_of(self.running_release)

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["ok"] = self.ok
        data["version"] = self.version
        return data


@dataclass(frozen=True)
class FleetResult:
    command: str
    hosts: tuple[HostResult, ...]
    aborted: bool = False          # max_fail stopped the rollout
    fleet_rollback: tuple[HostResult, ...] = ()   # robots of earlier waves returned to their old release
    interrupted: bool = False
    seconds: float = 0.0
    run_id: str = ""

    @property
    def ok(self) -> bool:
        return all(h.ok for h in self.hosts) and not self.aborted and not self.interrupted

    def to_json(self) -> dict[str, Any]:
        return {"command": self.command, "ok": self.ok, "aborted": self.aborted,
                "interrupted": self.interrupted, "seconds": round(self.seconds, 2), "run_id": self.run_id,
                "hosts": [h.to_json() for h in self.hosts],
                "fleet_rollback": [h.to_json() for h in self.fleet_rollback]}


def version_of(release_id: str | None) -> str | None:
    return release_id.rsplit("-", 1)[0] if release_id and "-" in release_id else release_id
