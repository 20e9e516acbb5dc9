"""The readiness gate: may this robot restart its services now?

Checked on the robot after the pull and before anything restarts (deploy.py). A robot
that is not ready is *deferred*: its images are pulled, nothing restarts, and the gate
is read again every `interval` until `max_wait`; then the robot is `busy`, with the
condition that held it and the value last seen.

    ready:
      interval: 10s          # between checks of a deferred robot
      max_wait: 10m          # then `busy` (pending: `apply --until` retries it later)
      topic_wait: 3s         # how long a ROS condition listens for a message
      when:
        - {topic: /robot_mode, field: data, is: IDLE}
        - {topic: /battery_state, field: percentage, at_least: 0.3}
        - {topic: /cmd_vel, quiet: 5s}                    # silent, or only zeros, for 5 s
        - {service: driver, command: [test, -e, /tmp/idle]}   # exit 0 in the running container
        - {lock: /var/lib/acme/update.lock}               # absent = ready (balena's convention)

The fleet file's `ready:` applies to every robot; an inventory var `ready:` (group or
host) replaces it for those robots, and `ready: false` turns the gate off there.

A robot with nothing running yet (first deploy, or the service is not running) passes the
ROS and command conditions by definition: no mission of ours can be under way, and there
is no container to ask. The lock file is a file on the robot and is checked regardless.
"""
from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass
from typing import Any, Callable, ContextManager, Mapping

from rosdeploy import commands
from rosdeploy.errors import shown
from rosdeploy.suggest import did_you_mean
from rosdeploy.yamlsrc import Doc, dotted

# The comparison keys of a topic condition, as YAML-friendly words.
OPS = {"is": "==", "is_not": "!=", "at_least": ">=", "at_most": "<=", "above": ">", "below": "<"}
# ROS 2 field names start with a letter: `__class__.__init__.__globals__` never reaches the probe's getattr
FIELD_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*(\.[A-Za-z][A-Za-z0-9_]*)*")
TOPIC_RE = re.compile(r"(?!.*__)(/[A-Za-z_][A-Za-z0-9_]*)+")   # ROS 2 names: no `__` anywhere
LOCK_PATH_RE = re.compile(r"(~/|/)[A-Za-z0-9_.@+-]+(/[A-Za-z0-9_.@+-]+)*")
SERVICE_RE = re.compile(r"[a-z0-9][a-z0-9_-]{0,62}")


@dataclass(frozen=True)
class Condition:
    """One condition; `kind` is topic (field compared), quiet (topic silent or zero), command or lock."""

    kind: str
    topic: str = ""
    field: str = ""
    op: str = ""             # one of OPS' values
    value: Any = None
    quiet: float = 0.0       # seconds
    service: str = ""
    command: tuple[str, ...] = ()
    path: str = ""           # lock file on the robot

    def describe(self) -> str:
        if self.kind == "topic":
            return f"{self.topic}.{self.field} {self.op} {json.dumps(self.value)}"
        if self.kind == "quiet":
            return f"{self.topic} quiet for {self.quiet:g}s"
        if self.kind == "command":
            return f"`{' '.join(self.command)}` in {self.service}"
        return f"lock file {self.path} absent"


@dataclass(frozen=True)
class ReadyPolicy:
    conditions: tuple[Condition, ...]
    interval: float = 10.0
    max_wait: float = 600.0
    topic_wait: float = 3.0

    @property
    def lock_paths(self) -> tuple[str, ...]:
        return tuple(c.path for c in self.conditions if c.kind == "lock")


@dataclass(frozen=True)
class Readiness:
    ok: bool
    condition: str = ""      # the first failing condition, described
    observed: str = ""       # what was seen instead

    @property
    def reason(self) -> str:
        return f"{self.condition} does not hold (observed: {self.observed})" if not self.ok else "ready"


# ------------------------------------------------------------------ reading

_POLICY_KEYS = ("interval", "max_wait", "topic_wait", "when")
_KINDS = {"topic": ("topic", "field", *OPS, "quiet"), "service": ("service", "command"), "lock": ("lock",)}


def convert(r: Any, kp: tuple, value: Any) -> ReadyPolicy | bool | None:
    """A fleet-file converter (fleet.Reader protocol): `ready:` -> ReadyPolicy, False (gate off),
    or None after reporting problems with r.error(keypath, message)."""
    from rosdeploy.fleet import parse_duration

    before = len(r.problems)
    if value is False or not known_keys(r, kp, value, _POLICY_KEYS, "a mapping with `when:` (a list of "
                                        "conditions) and optionally interval, max_wait, topic_wait"):
        return False if value is False else None
    times = {}
    for key in ("interval", "max_wait", "topic_wait"):
        if key in value:
            try:
                times[key] = parse_duration(value[key])
            except ValueError:
                r.error(kp + (key,), f"must be a duration like 10s, 2m or 1h; got {shown(value[key])}")
    if times.get("interval") == 0:
        r.error(kp + ("interval",), "must be above 0 (the pause between two checks)")
    if times.get("topic_wait") == 0:
        r.error(kp + ("topic_wait",), "must be above 0 (how long a ROS condition listens for a message): a "
                                      "topic condition would hear nothing, e.g. 3s")
    when = value.get("when")
    if not isinstance(when, list) or not when:
        r.error(kp + ("when",), "required: a list of conditions, e.g. `- {topic: /robot_mode, field: data, is: IDLE}`")
        return None
    conditions = tuple(_condition(r, kp + ("when", i), c) for i, c in enumerate(when))
    if len(r.problems) > before or None in conditions:   # None: refused, its problem maybe shown elsewhere
        return None
    return ReadyPolicy(conditions, **times)   # type: ignore[arg-type]


def known_keys(r: Any, kp: tuple, value: Any, keys: tuple[str, ...], shape: str) -> bool:
    """Is `value` a mapping? Reports it if not (or false, to turn the setting off), and every
    unknown key with a did-you-mean."""
    if not isinstance(value, dict):
        r.error(kp, f"must be {shape}; or false to turn it off")
        return False
    for key in value:
        if key not in keys:
            r.error(kp + (key,), f"unknown key `{key}`: {did_you_mean(key, keys) or 'use ' + ', '.join(keys)}")
    return True


def _condition(r: Any, kp: tuple, value: Any) -> Condition | None:
    kind = next((k for k in _KINDS if isinstance(value, dict) and k in value), None)
    if kind is None:
        r.error(kp, "a condition is a mapping with `topic:` (a ROS topic), `service:` + `command:` "
                    "(run in a running container) or `lock:` (a lock file on the robot)")
        return None
    for key in value:
        if key not in _KINDS[kind]:
            r.error(kp + (key,), f"unknown key `{key}` in a {kind} condition: "
                                 f"{did_you_mean(key, _KINDS[kind]) or 'use ' + ', '.join(_KINDS[kind])}")
    return {"topic": _topic, "service": _command, "lock": _lock}[kind](r, kp, value)


def _topic(r: Any, kp: tuple, value: dict) -> Condition | None:
    from rosdeploy.fleet import parse_duration

    topic = value["topic"]
    if not isinstance(topic, str) or not TOPIC_RE.fullmatch(topic):
        r.error(kp + ("topic",), f"{shown(topic)} is not an absolute ROS topic name, e.g. /robot_mode")
        return None
    if "quiet" in value:
        extra = [k for k in ("field", *OPS) if k in value]
        if extra:    # a quiet condition compares nothing: `is:` would silently be dropped
            r.error(kp + (extra[0],), f"`quiet:` (the topic silent, or only zeros) takes no `{extra[0]}`: make "
                                      "it a condition of its own, with `field:` and one comparison")
            return None
        try:
            return Condition("quiet", topic=topic, quiet=parse_duration(value["quiet"]))
        except ValueError:
            r.error(kp + ("quiet",), f"must be a duration like 5s; got {shown(value['quiet'])}")
            return None
    ops = [k for k in OPS if k in value]
    if len(ops) != 1:
        r.error(kp, f"give exactly one comparison ({', '.join(OPS)}) or `quiet: 5s`")
        return None
    field, expected = value.get("field"), value[ops[0]]
    if not isinstance(field, str) or not FIELD_RE.fullmatch(field.lstrip(".")):
        r.error(kp + ("field",), "required: the message field to compare, e.g. `data` or `pose.position.x`")
        return None
    if not isinstance(expected, (str, int, float, bool)):
        r.error(kp + (ops[0],), "must be a string, number or true/false")
        return None
    if isinstance(expected, float) and not math.isfinite(expected):   # `.nan` equals nothing: never ready
        r.error(kp + (ops[0],), f"must be a finite number; got {shown(expected)}")
        return None
    if OPS[ops[0]] not in ("==", "!=") and (isinstance(expected, bool) or not isinstance(expected, (int, float))):
        r.error(kp + (ops[0],), f"`{ops[0]}` compares numbers; got {shown(expected)}")
        return None
    return Condition("topic", topic=topic, field=field.lstrip("."), op=OPS[ops[0]], value=expected)


def _command(r: Any, kp: tuple, value: dict) -> Condition | None:
    service, command = value["service"], value.get("command")
    if not isinstance(service, str) or not SERVICE_RE.fullmatch(service):
        r.error(kp + ("service",), f"{shown(service)} is not a service name")
        return None
    if isinstance(command, str):
        # an empty shell line exits 0: the condition would always hold
        command = ["sh", "-c", command] if command.strip() else []
    if not isinstance(command, list) or not command or not all(isinstance(a, (str, int, float)) for a in command):
        r.error(kp + ("command",), "required: the command to run in the container, as a list "
                                   "([test, -e, /tmp/idle]) or one shell line")
        return None
    if not str(command[0]).strip():     # no program: the exec fails, and the condition never holds
        r.error(kp + ("command", 0), "is empty: the first word is the program to run, e.g. [test, -e, /tmp/idle]")
        return None
    return Condition("command", service=service, command=tuple(str(a) for a in command))


def _lock(r: Any, kp: tuple, value: dict) -> Condition | None:
    path = value["lock"]
    if not isinstance(path, str) or not LOCK_PATH_RE.fullmatch(path) or ".." in path.split("/"):
        r.error(kp + ("lock",), f"{shown(path)} is not a path on the robot: absolute or under ~/, "
                                "letters, digits and ._@+- only")
        return None
    return Condition("lock", path=path)


def check_services(policy: ReadyPolicy, services: Mapping[str, Any], r: Any, kp: tuple) -> None:
    """A command condition must name a service of the fleet file."""
    for i, c in enumerate(policy.conditions):
        if c.kind == "command" and c.service not in services:
            hint = did_you_mean(c.service, services) or "the services are: " + ", ".join(services)
            r.error(kp + ("when", i, "service"), f"no service is named `{c.service}`: {hint}")


# ----------------------------------------------------------------- comparing

def compare(observed: Any, op: str, expected: Any) -> bool:
    """Observed message value against the condition; a type mismatch is simply not ready."""
    if op in ("==", "!="):
        same = observed == expected or (isinstance(observed, (int, float)) and not isinstance(observed, bool)
                                        and isinstance(expected, (int, float)) and float(observed) == float(expected))
        return same if op == "==" else not same
    if isinstance(observed, bool) or not isinstance(observed, (int, float)):
        return False
    return {">=": observed >= expected, "<=": observed <= expected,
            ">": observed > expected, "<": observed < expected}[op]


def judge(conditions: tuple[Condition, ...], report: Mapping) -> Readiness:
    """The probe's report (observed values per topic condition) -> the first condition that fails."""
    ros = [c for c in conditions if c.kind in ("topic", "quiet")]
    observed = list(report.get("ready", []))
    observed += [{"error": "the probe did not report it"}] * (len(ros) - len(observed))   # never "ready" by omission
    for c, seen in zip(ros, observed[:len(ros)], strict=True):
        if c.kind == "topic":
            if "value" not in seen:
                return Readiness(False, c.describe(), seen.get("error", "no message"))
            if not compare(seen["value"], c.op, c.value):
                return Readiness(False, c.describe(), json.dumps(seen["value"]))
        elif not seen.get("quiet", False):
            return Readiness(False, c.describe(), seen.get("error") or f"moving: {json.dumps(seen.get('value'))}")
    return Readiness(True)


def lock_holder(stdout: str) -> dict | None:
    """The lock-file command's answer: None when absent, else {holder, since}."""
    line = stdout.strip().splitlines()[-1] if stdout.strip() else ""
    if not line.startswith("held "):
        return None
    _, mtime, *holder = line.split(" ", 2)
    since = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(int(mtime))) if mtime.isdigit() else "?"
    return {"holder": (holder[0] if holder else "").strip() or "unknown", "since": since,
            "age": int(time.time()) - int(mtime) if mtime.isdigit() else None}


# ------------------------------------------------------------ on the robot

LOCK_SCRIPT = commands.load("app-lock.sh")


def lock_command(path: str) -> commands.Command:
    return commands.script("app-lock", LOCK_SCRIPT, path)


def exec_command(container: str, argv: tuple[str, ...], timeout: float) -> commands.Command:
    return commands.Command(("docker", "exec", container, *argv), timeout=timeout,
                            label=f"ready: docker exec {container} {' '.join(argv)}")


Run = Callable[[commands.Command], Any]   # Transport.run


def check(run: Run, policy: ReadyPolicy, running: Mapping[str, str], probe_in: str | None,
          probe_source: str) -> Readiness:
    """Every condition, cheapest first; the first failing one is the answer.

    `running`: service -> name of its running container; `probe_in`: the container the
    ROS probe runs in (None when nothing runs: ROS conditions hold by definition)."""
    for c in policy.conditions:
        if c.kind == "lock":
            held = lock_holder(run(lock_command(c.path)).stdout)
            if held:
                return Readiness(False, c.describe(), f"held by {held['holder']} since {held['since']}")
        elif c.kind == "command" and c.service in running:
            out = run(exec_command(running[c.service], c.command, timeout=30.0))
            if not out.ok:
                tail = (out.stdout + out.stderr).strip().splitlines()[-1:] or [""]
                return Readiness(False, c.describe(), f"exit {out.exited} {tail[0][:120]}".strip())
    ros = tuple(c for c in policy.conditions if c.kind in ("topic", "quiet"))
    if not ros or probe_in is None:
        return Readiness(True)
    spec = {"ready": [_probe_entry(c) for c in ros], "wait": policy.topic_wait}
    wait = max([policy.topic_wait] + [c.quiet for c in ros])
    out = run(commands.ros_probe(probe_in, probe_source, spec, timeout=wait + 30))
    report = _last_json(out.stdout)
    if report is None or "ready" not in report:
        tail = " ".join((out.stderr or out.stdout).strip().splitlines()[-2:])
        return Readiness(False, ros[0].describe(), f"probe could not run: {tail or 'no output'}")
    return judge(ros, report)


def _probe_entry(c: Condition) -> dict:
    return {"topic": c.topic, "field": c.field} if c.kind == "topic" else {"topic": c.topic, "quiet": c.quiet}


def _last_json(text: str) -> dict | None:
    for line in reversed(text.strip().splitlines()):
        try:
            found = json.loads(line)
        except ValueError:
            continue
        if isinstance(found, dict):
            return found
    return None


def wait_ready(check_once: Callable[[], Readiness], policy: ReadyPolicy, cancelled: Callable[[], bool],
               note: Callable[[str], None], step: Callable[[str], ContextManager[None]]) -> Readiness | None:
    """Check, then every `interval` until ready or `max_wait`; None when cancelled meanwhile."""
    deadline = time.monotonic() + policy.max_wait
    with step("ready"):
        verdict = check_once()
    while not verdict.ok and time.monotonic() + policy.interval <= deadline + 1e-3:
        note(f"deferred: {verdict.reason}; next check in {policy.interval:g}s")
        end = time.monotonic() + policy.interval
        while time.monotonic() < end:
            if cancelled():
                return None
            time.sleep(min(0.2, max(0.0, end - time.monotonic())))
        with step("ready"):
            verdict = check_once()
    return verdict


# ------------------------------------------------------- per group / host

# The inventory vars (group or host; also as rosdeploy_ready, rosdeploy_window) that replace
# the fleet file's settings for those robots.
GATE_VARS = {"ready": "readiness gate (a mapping with `when:`, or false)",
             "window": "maintenance window (a mapping with start and duration, or false)"}


def is_gate_shaped(value: Any) -> bool:
    """Could this short `ready`/`window` var be rosdeploy's (a mapping, or false/true)? Another
    tool's value (`ready=true` as INI text, `window=off`) is not, and rosdeploy ignores it."""
    return isinstance(value, (Mapping, bool))


def checked_var(name: str) -> Callable[[Any], Any]:
    """The inventory's converter of a `ready`/`window` var: checked where it is set (the
    inventory names the file and line), kept as written for host_setting."""
    def check(value: Any) -> Any:
        from rosdeploy.inventory.hostvars import BadValue
        from rosdeploy.window import convert as convert_window

        found: list[tuple[tuple, str]] = []
        reader = _Collect(found)
        (convert if name == "ready" else convert_window)(reader, (), value)
        if found:
            more = f" (and {len(found) - 1} more problem(s) in it)" if len(found) > 1 else ""
            raise BadValue(f"{dotted((name, *found[0][0]))}: {found[0][1]}{more}", found[0][0])
        return value
    return check


class _Collect:
    """The reader protocol of the converters above, collecting (keypath, message)."""

    def __init__(self, found: list) -> None:
        self.problems = found

    def error(self, kp: tuple, message: str) -> None:
        self.problems.append((kp, message))


def host_setting(spec: Any, host: Any, var: str, problems: list | None = None) -> Any:
    """The robot's `ready` or `window`: its inventory var (group or host; `rosdeploy_` + var
    wins) replaces the fleet file's; false turns it off. The inventory checked the value
    where it is set; what needs the fleet file (a command condition's service) is checked
    here, into `problems`, located where the robot is declared."""
    from rosdeploy.fleet import Reader
    from rosdeploy.window import convert as convert_window

    used = next((name for name in ("rosdeploy_" + var, var) if name in host.vars), None)
    if used == var and not is_gate_shaped(host.vars[var]):
        used = None     # another tool's `ready`/`window`: the inventory warned it is ignored, and it is
    if used is None:
        return getattr(spec, var)
    path, _, line = host.source.rpartition(":")
    r = Reader(Doc(path or host.source, host.vars, {(): int(line)} if line.isdigit() else {}))
    value = (convert if var == "ready" else convert_window)(r, (host.name, used), host.vars[used])
    if isinstance(value, ReadyPolicy):
        check_services(value, {s.name: s for s in spec.services}, r, (host.name, used))
    if problems is not None:
        problems.extend(r.problems)
    return None if r.problems or value is False else value


def host_problems(spec: Any, hosts: Any) -> list:
    """Problems of the robots' `ready`/`window` vars that only the fleet file can tell."""
    problems: list = []
    for host in hosts:
        for var in GATE_VARS:
            host_setting(spec, host, var, problems)
    return problems
