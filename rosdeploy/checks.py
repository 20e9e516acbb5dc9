"""The ROS 2 deployment checklist (README: "What `validate` and `check` enforce"), as rules.

Each rule is a small function registered with an id, a severity and a fix. They
run over the fleet spec, the inventory hosts and what each robot would really
receive: the rendered compose.yml is parsed back (with the robot's .env
interpolated, as compose would) so a user's own templates are held to the same
checklist as the built-in ones.

Four scopes, by what a rule needs to see:
    fleet    (ctx)                          robots compared with each other
    host     (ctx, host)                    one robot's inventory against the fleet file
    release  (ctx, target)                  one robot's rendered files as a whole
    service  (ctx, target, name, service)   one service of one robot's rendered compose

A finding found identically on many robots is reported once, naming the robots
(the `{robots}` placeholder), so 200 robots with the same template bug give one line.
Severities: error (refused by validate and deploy), warning, info.
"""
from __future__ import annotations

import functools
import os
import posixpath
import re
import xml.etree.ElementTree as ET
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence, cast

import yaml

from rosdeploy import yamlsrc
from rosdeploy.compose_env import interpolate, read_env, substitute
from rosdeploy.errors import InputError, Problem, shown
from rosdeploy.files import reads_as_number
from rosdeploy.fleet import problem_at, size_bytes, sysctl_names, sysctl_refusal
from rosdeploy.inventory.hostvars import PREFIX, case_variant
from rosdeploy.model import FleetSpec, Host, RenderedRelease, Service
from rosdeploy.output import LONG_SECRET

SEVERITIES = ("error", "warning", "info")
TARGET_SCOPES = ("release", "service")    # rules that see one robot's release and nothing else
ROBOTS = "{robots}"
MB = 1024 * 1024
STABLE_DEVICE_PREFIXES = ("/dev/robot/", "/dev/serial/by-id/", "/dev/serial/by-path/", "/dev/v4l/by-id/",
                          "/dev/v4l/by-path/", "/dev/disk/by-")
IMAGE_TOPIC_RE = re.compile(r"image|camera|depth|compressed|rgb|points", re.IGNORECASE)
ROTATING_LOG_DRIVERS = ("local", "journald")   # rotate on their own; json-file needs max-size/max-file


@dataclass(frozen=True)
class Rule:
    id: str
    severity: str
    scope: str
    summary: str        # what the rule enforces, for docs and `check --json`
    fix: str            # the general fix; each finding's message says the specific one
    func: Callable[..., Iterable[Any]]


RULES: dict[str, Rule] = {}


def rule(rule_id: str, severity: str, scope: str, summary: str, fix: str) -> Callable:
    def register(func: Callable) -> Callable:
        RULES[rule_id] = Rule(rule_id, severity, scope, summary, fix, func)
        return func
    return register


@dataclass(frozen=True)
class Target:
    """One robot as the checks see it: its host, its release and the compose file parsed back."""

    host: Host
    release: RenderedRelease
    env: Mapping[str, str] = field(default_factory=dict)          # the rendered .env
    compose: Mapping[str, Any] | None = None                        # interpolated; None: unparsable
    raw_compose: Mapping[str, Any] | None = None                    # before interpolation
    compose_error: str = ""
    compose_error_line: int | None = None   # of the rendered compose.yml, where compose_error is
    env_problems: tuple[str, ...] = ()   # "line N: why" of .env lines Compose v1 reads otherwise, or unseen

    @property
    def services(self) -> Mapping[str, Any]:
        services = (self.compose or {}).get("services")
        return services if isinstance(services, dict) else {}

    @functools.cached_property    # per robot: docker-socket-mounted and mount-system-writable share them
    def mounts(self) -> dict[str, tuple[tuple[str, str, bool], ...]]:
        """Service name -> its mounts of robot paths, as _robot_mounts finds them (filled as asked)."""
        return {}

    @functools.cached_property
    def folder_vars(self) -> tuple[str, str]:
        """The robot's rosdeploy_home and rosdeploy_deploy_root ("" when unset): read once, not per rule."""
        return (str(self.host.vars.get("rosdeploy_home") or ""), str(self.host.vars.get("rosdeploy_deploy_root") or ""))

    @functools.cached_property    # frozen, and asked once per service
    def bind_volumes(self) -> Mapping[str, tuple[str, bool]]:
        """Top-level volumes the local driver binds from a robot path (`driver_opts: {type: none,
        o: bind, device: /}`), as name -> (device, read-only): a bind mount by another name."""
        volumes = (self.compose or {}).get("volumes")
        found: dict[str, tuple[str, bool]] = {}
        for name, volume in (volumes.items() if isinstance(volumes, dict) else ()):
            if not isinstance(volume, dict):
                continue
            opts = _dig(volume, "driver_opts")
            options = str(opts.get("o", "")).replace(" ", "").split(",")
            if volume.get("driver", "local") in ("local", None) and ("bind" in options or "rbind" in options) and \
                    opts.get("device"):
                found[str(name)] = (str(opts.get("device", "")), "ro" in options)
        return found

    @functools.cached_property    # frozen, and asked once per service
    def disk_volumes(self) -> Mapping[str, tuple[str, str, bool]]:
        """Top-level volumes the local driver mounts from a robot device as a file system
        (`driver_opts: {type: ext4, device: /dev/sda1}`), as name -> (device, type, read-only): the engine
        mounts the robot's disk itself, so the container reads (or writes) every file on it. A bind (`o: bind`,
        bind_volumes), `type: none`, a remote file system (nfs, cifs: `device` is no /dev path) and
        tmpfs are not."""
        volumes = (self.compose or {}).get("volumes")
        found: dict[str, tuple[str, str, bool]] = {}
        for name, volume in (volumes.items() if isinstance(volumes, dict) else ()):
            opts = _dig(volume, "driver_opts")
            device = opts.get("device")
            if not isinstance(device, str) or not device.startswith("/") or volume.get("external") or \
                    volume.get("driver", "local") not in ("local", None):
                continue
            kind = str(opts.get("type", ""))
            options = str(opts.get("o", "")).replace(" ", "").split(",")
            device = _normal_path(device)
            if (device == "/dev" or device.startswith("/dev/")) and kind not in ("none", "bind", "rbind") and \
                    not ("bind" in options or "rbind" in options):
                found[str(name)] = (device, kind, "ro" in options)
        return found


@dataclass(frozen=True)
class Context:
    spec: FleetSpec
    hosts: tuple[Host, ...]             # the targeted robots
    all_hosts: tuple[Host, ...]         # the whole inventory: untargeted robots still talk DDS
    targets: tuple[Target, ...]

    def service(self, name: str) -> Service | None:
        return next((s for s in self.spec.services if s.name == name), None)


# ------------------------------------------------------------------ running

def run_checks(spec: FleetSpec, hosts: Sequence[Host],
               releases: Iterable[RenderedRelease] | Mapping[str, RenderedRelease], *,
               all_hosts: Sequence[Host] = (), rules: Iterable[Rule] | None = None,
               on_targets: Mapping[str, Sequence[tuple[Problem, str]]] | None = None) -> list[Problem]:
    """Every finding of every rule, merged across robots, sorted by severity, file and line.

    `all_hosts` is the whole inventory (robots outside --limit still talk DDS); default `hosts`.
    `on_targets`: the release and service rules' findings, already found where each release was
    rendered (TargetRules), as rule id -> [(problem, robot)] in robot order; they run again only
    without it.
    """
    ctx = make_context(spec, hosts, all_hosts, releases if on_targets is None else {})
    found: dict[Problem, dict[str, int | None]] = defaultdict(dict)   # a finding -> its robots, in order (a
    for r in (RULES.values() if rules is None else rules):              # set with order), each with its line
        ran = on_targets.get(r.id, ()) if on_targets is not None and r.scope in TARGET_SCOPES else _run_rule(r, ctx)
        for problem, robot in ran:
            line = None
            if RENDERED_MARK in problem.message:      # only a rendered file's error: none on a valid fleet
                problem, line = _lift_line(problem)
            if robot:
                found[problem][robot] = line
            else:
                found[problem]
    merged = [_with_robots(p, robots) for p, robots in found.items()]
    return sorted(merged, key=sort_key)


class TargetRules:
    """The release and service rules on one robot's release, where it was just rendered (a
    forked child, rosdeploy.forked): what run_checks would find on it, as (rule id, problem)."""

    def __init__(self, spec: FleetSpec) -> None:
        self.ctx = Context(spec, (), (), ())
        self.rules = [r for r in RULES.values() if r.scope in TARGET_SCOPES]
        self.located: dict[tuple, Problem] = {}

    def __call__(self, host: Host, release: RenderedRelease) -> tuple[tuple[str, Problem], ...]:
        target = parse_release(host, release)
        return tuple((r.id, p) for r in self.rules for p in _on_target(r, self.ctx, target, self.located))


def blocked_hosts(spec: FleetSpec, hosts: Sequence[Host]) -> set[str]:
    """Robots an error-level host rule fails (a device or secret they lack): they cannot be rendered."""
    ctx = make_context(spec, hosts, hosts, {})
    rules = [r for r in RULES.values() if r.scope == "host" and r.severity == "error"]
    return {h.name for h in hosts if any(any(True for _ in r.func(ctx, h)) for r in rules)}


def sort_key(p: Problem) -> tuple:
    severity = SEVERITIES.index(p.severity) if p.severity in SEVERITIES else len(SEVERITIES)
    return severity, p.file, p.line or 0, p.key, p.message


def make_context(spec: FleetSpec, hosts: Sequence[Host], all_hosts: Sequence[Host],
                 releases: Iterable[RenderedRelease] | Mapping[str, RenderedRelease]) -> Context:
    by_name = dict(releases) if isinstance(releases, Mapping) else {r.host: r for r in releases}
    targets = tuple(parse_release(h, by_name[h.name]) for h in hosts if h.name in by_name)
    return Context(spec, tuple(hosts), tuple(all_hosts) or tuple(hosts), targets)


def _run_rule(r: Rule, ctx: Context) -> Iterator[tuple[Problem, str]]:
    if r.scope == "fleet":
        yield from ((_stamp(p, r), "") for p in r.func(ctx))
    elif r.scope == "host":
        for host in ctx.hosts:
            yield from ((_stamp(p, r), host.name) for p in r.func(ctx, host))
    else:
        located: dict[tuple, Problem] = {}
        for t in ctx.targets:
            yield from ((p, t.host.name) for p in _on_target(r, ctx, t, located))


def _on_target(r: Rule, ctx: Context, t: Target, located: dict[tuple, Problem]) -> Iterator[Problem]:
    """A release or service rule's findings on one robot's release."""
    if r.scope == "release":
        yield from (_stamp(p, r) for p in r.func(ctx, t))
        return
    # Most robots give the same findings (the message says {robots}): locate each one once.
    for name, svc in t.services.items():
        for keypath, message in r.func(ctx, t, name, svc if isinstance(svc, dict) else {}):
            p = located.get((r.id, name, keypath, message))
            if p is None:
                p = located[r.id, name, keypath, message] = _stamp(_service_problem(ctx.spec, name, keypath,
                                                                                    message), r)
            yield p


def _service_problem(spec: FleetSpec, name: str, keypath: tuple, message: str) -> Problem:
    """Located at the fleet key to fix, or at the service when that key is not in the file at all.

    With a user compose template the fleet file may be right and the template wrong: say so.
    """
    if keypath[0] != "services" and keypath[:1] not in spec.lines:
        keypath = ("services", name)
    if spec.templates and (Path(spec.templates) / "compose.yml.j2").is_file():
        message += f" (this compose.yml comes from your template {Path(spec.templates) / 'compose.yml.j2'})"
    return problem_at(spec, keypath, message)


def _stamp(p: Problem, r: Rule) -> Problem:
    return Problem(p.file, p.line, p.key, p.message, r.severity, r.id)


def rendered_line(line: int | None, name: str) -> str:
    """A line of the file `name` a template renders, in a finding's message: the line differs by
    robot where the values above it do, so run_checks groups the robots without it and says it
    only when they all share it (_with_robots)."""
    return f"{{rendered line {line or 0} of {name}}}"


RENDERED_MARK = "{rendered line "
_RENDERED_LINE = re.compile(r"\{rendered line (\d+) of ([^{}]*)\}")


def _lift_line(p: Problem) -> tuple[Problem, int | None]:
    """The problem with its rendered line taken out of the message (the grouping key), and the line."""
    found = _RENDERED_LINE.search(p.message)
    if found is None:
        return p, None
    message = p.message[:found.start()] + rendered_line(None, found[2]) + p.message[found.end():]
    return Problem(p.file, p.line, p.key, message, p.severity, p.rule), int(found[1]) or None


def _put_line(message: str, lines: Iterable[int | None]) -> str:
    shared = set(lines)

    def said(found: re.Match) -> str:
        of = f" of the {found[2]} it renders" if found[2] else ""    # no name: the message says the file
        if len(shared) > 1:
            return f"a line{of} (which line differs by robot)"
        line = next(iter(shared), None)
        return f"line {line}{of}" if line else f"the {found[2]} it renders"
    return _RENDERED_LINE.sub(said, message)


def _with_robots(p: Problem, robots: Mapping[str, int | None]) -> Problem:
    if RENDERED_MARK in p.message:
        p = Problem(p.file, p.line, p.key, _put_line(p.message, robots.values()), p.severity, p.rule)
    if ROBOTS not in p.message:
        return p
    # quoted: a robot name is the inventory's text, and one with a newline must not split the message
    names = list(robots)
    shown = ", ".join(map(repr, names[:5])) + (f" (+{len(names) - 5} more)" if len(names) > 5 else "")
    return Problem(p.file, p.line, p.key, p.message.replace(ROBOTS, shown), p.severity, p.rule)


def host_problem(host: Host, key: str, message: str) -> Problem:
    """A problem located at the var `key` where its value was set (a host_vars or group_vars file);
    else where the robot is declared in the inventory (Host.source is "file:line")."""
    origin = host.vars.origin(key) if key and hasattr(host.vars, "origin") else None
    if origin is not None:
        return origin.problem((key,), message)
    file, _, line = host.source.rpartition(":")
    if not (line.isascii() and line.isdigit()):
        return Problem(host.source or "inventory", None, key, message)
    return Problem(file, int(line), key, message)


def _set_at(host: Host, key: str) -> str:
    """"file:line" where the robot's `key` was set, for naming the other side of a clash."""
    found = host_problem(host, key, "")
    return f"{found.file}:{found.line}" if found.line else found.file


# ------------------------------------------------------- parsing a release

def parse_release(host: Host, release: RenderedRelease) -> Target:
    """The release's compose.yml parsed back, with ${VARS} taken from its .env the way compose does."""
    names = {f.name: f for f in release.files}
    env, problems = read_env(names[".env"].content) if ".env" in names else ({}, [])
    env_problems = tuple(problems)
    if "compose.yml" not in names:
        return Target(host, release, env, None, None, "no compose.yml was rendered", env_problems=env_problems)
    if release.compose_data is not None:   # the built-in template's output, as data: no parse
        raw, resolved = release.compose_data
        return Target(host, release, env, resolved, raw, "", env_problems=env_problems)
    try:
        # load(), not load_data(): a user template can render a key twice, which Compose v2 refuses
        raw = yamlsrc.load("compose.yml", text=names["compose.yml"].content).data
    except InputError as exc:
        return Target(host, release, env, None, None, _yaml_error(exc.problems[0]), exc.problems[0].line,
                      env_problems=env_problems)
    if not isinstance(raw, dict):
        why = "it is empty" if raw is None else "it is not a mapping"
        return Target(host, release, env, None, None, why, env_problems=env_problems)
    return Target(host, release, env, interpolate(raw, env), raw, "", env_problems=env_problems)


def _yaml_error(p: Problem) -> str:
    if "another document" in p.message:     # PyYAML's "expected a single document ...", cut short by yamlsrc
        return ("it holds more than one YAML document (a `---`): Compose v2 merges them, and `check` reads one; "
                "remove the `---`")
    return p.message


_NEWLINE = re.compile(r"\r\n|\r|\n")     # Jinja's, which numbers a template's lines
_YAML_BREAK = re.compile(r"\r\n|[\r\n\x85\u2028\u2029]")     # PyYAML's, which numbers a rendered file's
_XML_BREAK = _NEWLINE     # expat's
_LF = re.compile(r"\n")    # compose_env.read_env's


def _template_lines(path: str) -> tuple[str, ...]:
    try:
        stat = os.stat(path)
    except OSError:
        return ()
    return _template_lines_of(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=16)
def _template_lines_of(path: str, mtime: int, size: int) -> tuple[str, ...]:
    """A user template's lines (the renderer read it already: a regular file within its bound), or
    none; read once per version of the file, for the robots whose release it fails."""
    from rosdeploy.files import MAX_TEMPLATE_BYTES
    try:
        return tuple(_NEWLINE.split(yamlsrc.read_bytes(path, MAX_TEMPLATE_BYTES, "a template").decode("utf-8")))
    except (InputError, UnicodeDecodeError):
        return ()


def template_line(template: str, rendered: str, line: int | None, breaks: re.Pattern = _YAML_BREAK) -> int | None:
    """The line of the template that wrote line `line` of `rendered`, where that is sure: the
    rendered line's text stands literally in the template, on one line and nowhere else. A line a
    value or a partial wrote has no such twin: None, rather than a guess."""
    lines = breaks.split(rendered)
    text = lines[line - 1].strip() if line and line <= len(lines) else ""
    if len(text) < 3:     # `]`, `- `: on many lines, proof of nothing
        return None
    sources = _template_lines(template)
    # the whole line, not a part of one: `x: 1` is in `x: 10`, which wrote something else
    found = [i for i, source in enumerate(sources, 1) if source.strip() == text]
    return found[0] if len(found) == 1 else None


def _content(t: Target, name: str) -> str:
    return next((f.content for f in t.release.files if f.name == name), "")


def _rendered_at(spec: FleetSpec, t: Target, name: str, template: str, line: int | None,
                 breaks: re.Pattern = _YAML_BREAK) -> tuple[str, str]:
    """(which template, where in it) for a finding on the file `name` a template rendered: the
    user's template named, with the line that wrote `line` when it is sure (template_line)."""
    if not _overridden(spec.templates, template):
        return f"the {name} rendered for {ROBOTS}", rendered_line(line, name) if line else ""
    source = str(Path(str(spec.templates)) / template)
    at = template_line(source, _content(t, name), line, breaks)
    where = (rendered_line(line, name) if line else "") + (f", written by line {at} of the template" if at else "")
    return f"the {name} your template {source} renders for {ROBOTS}", where


def env_of(svc: Mapping[str, Any]) -> dict[str, str]:
    """A compose service's environment, written as a mapping or as a list of KEY=VALUE."""
    env = svc.get("environment") or {}
    if isinstance(env, list):
        return {k: v for k, _, v in (str(item).partition("=") for item in env)}
    return {str(k): "" if v is None else str(v) for k, v in env.items()} if isinstance(env, dict) else {}


@functools.lru_cache(maxsize=1024)
def dds_peers(xml_text: str) -> tuple[str, ...]:
    """Unicast peers in a CycloneDDS (<Peer address=...>) or Fast DDS (initialPeersList) config.

    Cached: robots on one domain ID share their profile byte for byte (5,000 robots, ~100 texts)."""
    root = ET.fromstring(xml_text)
    peers = [el.get("address") or (el.text or "").strip() for el in root.iter() if _local(el.tag) == "Peer"]
    for plist in (el for el in root.iter() if _local(el.tag) == "initialPeersList"):
        peers += [(a.text or "").strip() for a in plist.iter() if _local(a.tag) == "address"]
    return tuple(p for p in peers if p)


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _size_or_none(value: Any) -> int | None:
    try:
        return size_bytes(value)
    except (ValueError, TypeError):
        return None


# ================================================================ the rules
# ---------------------------------------------------- robots and inventory

@rule("domain-id-duplicate", "error", "fleet", "Two robots on one network never share a ROS_DOMAIN_ID.",
      "Give every robot on a network (Host.network) its own ros_domain_id.")
def _domain_duplicates(ctx: Context) -> Iterator[Problem]:
    seen: dict[tuple[str, int], Host] = {}
    for host in ctx.all_hosts:
        if "ros_domain_id" not in host.vars:
            continue
        first = seen.setdefault((host.network, host.ros_domain_id), host)
        if first is not host:
            yield host_problem(host, "ros_domain_id", (
                f"{shown(host.name)} and {shown(first.name)} ({_set_at(first, 'ros_domain_id')}) both use "
                f"ros_domain_id {host.ros_domain_id} on network {shown(host.network)}: their DDS traffic would mix; "
                f"give {shown(host.name)} an unused ID (0-101)"))


@rule("domain-id-missing", "error", "host", "Every robot declares its ros_domain_id in the inventory.",
      "Add `ros_domain_id: N` (0-101, unique per network) to the robot's host vars.")
def _domain_missing(ctx: Context, host: Host) -> Iterator[Problem]:
    # the inventory reads rosdeploy_ros_domain_id before ros_domain_id, and a null as unset
    var = next((v for v in (PREFIX + "ros_domain_id", "ros_domain_id") if v in host.vars), "ros_domain_id")
    if host.vars.get(var) is None:
        # `ROS_DOMAIN_ID: 5`, the environment variable's spelling, is likely what the robot has
        other = case_variant(host.vars, "ros_domain_id") or case_variant(host.vars, PREFIX + "ros_domain_id")
        also = f" ({shown(other)} is set, but names are case-sensitive: rename it ros_domain_id)" if other else ""
        yield host_problem(host, other or var, (
            f"{shown(host.name)} declares no ros_domain_id{also}: without one it would join domain 0 with every "
            "other such robot; add `ros_domain_id: N` (0-101, unique on its network) to its host vars"))


@rule("fleet-octal-number", "warning", "fleet", "No number in the fleet file is written like 017, which YAML 1.1 "
      "(and so Ansible) reads as octal: 15.", "Write the number without its leading 0.")
def _fleet_octal(ctx: Context) -> Iterator[Problem]:
    yield from ctx.spec.warnings      # found as the file was read (yamlsrc._octal_warning)


@rule("order-by-unmatched", "warning", "fleet", "rollout.order_by is the prefix of a group of the targeted robots.",
      "Fix the prefix (e.g. site_), or remove rollout.order_by.")
def _order_by_unmatched(ctx: Context) -> Iterator[Problem]:
    prefix = ctx.spec.rollout.order_by
    if prefix and ctx.hosts and not any(g.startswith(prefix) for h in ctx.hosts for g in h.groups):
        yield problem_at(ctx.spec, ("rollout", "order_by"), (
            f"no group of the targeted robots starts with {shown(prefix)}: the rollout keeps the inventory's "
            "order, with no grouping; check the prefix"))


@rule("domain-id-range", "error", "host", "ROS_DOMAIN_ID is within 0-232.",
      "Use an ID from 0 to 101 (safe on every Linux host).")
def _domain_range(ctx: Context, host: Host) -> Iterator[Problem]:
    return _domain_findings(host, lambda d: not 0 <= d <= 232,
                            "{name} has ros_domain_id {id}: DDS accepts only 0-232; use 0-101")


@rule("domain-id-unsafe", "warning", "host", "ROS_DOMAIN_ID is within 0-101, the range safe on every Linux host.",
      "Use an ID from 0 to 101: 102-232 can collide with the host's ephemeral ports.")
def _domain_unsafe(ctx: Context, host: Host) -> Iterator[Problem]:
    return _domain_findings(host, lambda d: 102 <= d <= 232, (
        "{name} has ros_domain_id {id}: IDs 102-232 overlap the Linux ephemeral port range and can fail "
        "to bind; use 0-101"))


def _domain_findings(host: Host, bad: Callable[[int], bool], message: str) -> Iterator[Problem]:
    if "ros_domain_id" in host.vars and bad(host.ros_domain_id):
        yield host_problem(host, "ros_domain_id", message.format(name=repr(host.name), id=host.ros_domain_id))


@rule("device-undeclared", "error", "host", "Every device a service asks for is declared by the robot.",
      "Add the logical name to the robot's inventory `devices:` (name: /dev/robot/...), or remove it from the service.")
def _device_undeclared(ctx: Context, host: Host) -> Iterator[Problem]:
    for svc in ctx.spec.services:
        for i, device in enumerate(svc.devices):
            if device not in host.devices:
                yield problem_at(ctx.spec, ("services", svc.name, "devices", i), (
                    f"service {shown(svc.name)} needs device `{device}`, which the inventory does not declare for "
                    f"{ROBOTS}: add `{device}: /dev/robot/{device}` under their `devices:` (host or group vars), "
                    f"or remove it from the service"))


@rule("device-duplicate", "error", "host", "A service's devices are distinct paths on the robot.",
      "Keep one of the logical names that map to the same path in the service's `devices:`.")
def _device_duplicate(ctx: Context, host: Host) -> Iterator[Problem]:
    """Compose v1 refuses a `devices:` list with one entry twice ("non-unique elements"), and
    two logical names of the inventory can be the same /dev path on one robot."""
    for svc in ctx.spec.services:
        first: dict[str, str] = {}
        for i, device in enumerate(svc.devices):
            path = host.devices.get(device)
            if path is None or first.setdefault(path, device) == device:
                continue
            yield problem_at(ctx.spec, ("services", svc.name, "devices", i), (
                f"service {shown(svc.name)} maps devices `{first[path]}` and `{device}`, which are both "
                f"{shown(path)} on {ROBOTS}: Compose v1 refuses a device listed twice; keep one of them"))


@rule("secret-undefined", "error", "host", "Every `secrets:` entry names a variable the robot has.",
      "Define the variable in a vault-encrypted vars file of the inventory.")
def _secret_undefined(ctx: Context, host: Host) -> Iterator[Problem]:
    return _secret_findings(ctx, lambda var: var not in host.vars, (
        "{env} takes inventory variable `{var}`, which is not defined for {robots}: add it to a "
        "vault-encrypted vars file (e.g. group_vars/all/vault.yml)"))


@rule("secret-not-vaulted", "error", "host", "Secrets come from vault-encrypted files only.",
      "Move the variable into a vault-encrypted vars file.")
def _secret_not_vaulted(ctx: Context, host: Host) -> Iterator[Problem]:
    return _secret_findings(ctx, lambda var: var in host.vars and not _from_vault(host, var), (
        "{env} takes inventory variable `{var}`, which is plain text for {robots}, not from a vault "
        "file: move it into a vault-encrypted vars file so it is never committed in the clear"))


BECOME_PASSWORDS = ("ansible_become_password", "ansible_become_pass")


@rule("become-password-not-vaulted", "warning", "host", "A sudo password comes from a vault file.",
      "Move ansible_become_password into a vault-encrypted vars file, or pass --ask-become-pass.")
def _become_password_not_vaulted(ctx: Context, host: Host) -> Iterator[Problem]:
    for var in BECOME_PASSWORDS:
        if var in host.vars and not _from_vault(host, var):
            yield host_problem(host, var, f"{var} of {ROBOTS} is plain text, not from a vault file: move it into a "
                                          "vault-encrypted vars file (it is a sudo password on every robot)")


def _from_vault(host: Host, var: str) -> bool:
    """A vault value, or computed from one (`{{ vault_token|b64encode }}`)."""
    value = str(host.vars[var])    # read first: which vault var it came from is known once it is templated
    source = getattr(host.vars, "secret_source", None)
    return value in host.secret_values or (source is not None and source(var) is not None)


@rule("secret-empty", "error", "host", "Every `secrets:` var holds a value (not null, not empty).",
      "Give the variable a value in its vault-encrypted vars file.")
def _secret_empty(ctx: Context, host: Host) -> Iterator[Problem]:
    """At the vault var: null was written to .env as `None`, and an empty value makes compose's
    `${NAME:?...}` refuse the file at `up`, on the robot."""
    for var, env in _secret_vars(ctx):
        if var in host.vars and host.vars.get(var) in (None, ""):
            what = "null" if host.vars.get(var) is None else "empty"
            yield host_problem(host, var, (
                f"`{var}` of {ROBOTS} is {what}, and the service's {env} takes it: a secret needs a value (the "
                f"robot's compose refuses an empty `${{{env}:?}}` when it starts the services); give `{var}` one"))


@rule("secret-short", "warning", "host", f"Secrets are at least {LONG_SECRET} characters (shorter ones are masked in "
      "output only where they stand as a whole word).",
      "Use a longer secret.")
def _secret_short(ctx: Context, host: Host) -> Iterator[Problem]:
    return _secret_findings(ctx, lambda var: host.vars.get(var) not in (None, "") and
                            len(str(host.vars[var])) < LONG_SECRET, (
        f"`{{var}}` of {{robots}} is shorter than {LONG_SECRET} characters: rosdeploy masks a secret that short in "
        "its output only where it stands as a whole word, so it shows in a path or a name (`/dev/<secret>`, "
        "`<secret>.yaml`); use a longer value"))


def _secret_vars(ctx: Context) -> Iterator[tuple[str, str]]:
    """(inventory var, ENV name) of every `secrets:` entry, each var once."""
    seen: dict[str, str] = {}
    for svc in ctx.spec.services:
        for env, var in svc.secret_env.items():
            seen.setdefault(var, env)
    return iter(seen.items())


def _secret_findings(ctx: Context, bad: Callable[[str], bool], message: str) -> Iterator[Problem]:
    """One finding per `secrets:` entry whose inventory variable `bad` rejects."""
    for svc in ctx.spec.services:
        for env, var in svc.secret_env.items():
            if bad(var):
                yield problem_at(ctx.spec, ("services", svc.name, "secrets", env),
                                 message.format(env=env, var=var, robots=ROBOTS))


@rule("gpu-unavailable", "warning", "host", "A gpu service targets robots with `gpu: true`.",
      "Set `gpu: true` in the inventory of robots that have one, or expect the service without a GPU.")
def _gpu_unavailable(ctx: Context, host: Host) -> Iterator[Problem]:
    for svc in ctx.spec.services:
        if svc.gpu and not host.gpu:
            yield problem_at(ctx.spec, ("services", svc.name, "gpu"), (
                f"service {shown(svc.name)} wants a GPU, but the inventory gives none (`gpu: true`) to {ROBOTS}: "
                "it is deployed there without a GPU reservation; make sure it can run on the CPU"))


@rule("host-changes-no-root", "warning", "host", "Robots whose release has host changes can install them as root.",
      "Connect as root, or set ansible_become: true with sudo to root for the SSH user (or pass "
      "--no-host-changes to apply).")
def _host_changes_no_root(ctx: Context, host: Host) -> Iterator[Problem]:
    from rosdeploy.hostchanges import become
    if not (host.udev or ctx.spec.log_rotate_every is not None):
        return
    refused = become(host).refused
    if refused:
        yield host_problem(host, refused.split(" ", 1)[0], (   # each refusal starts with its var
            f"robot {host.name!r} gets udev rules or log rotation, which are installed as root, and {refused}; "
            "apply fails there whenever they change"))


# ------------------------------------------------------- a robot's release

@rule("compose-invalid", "error", "release",
      "The rendered compose.yml is one YAML document with a `services` mapping, brings in nothing `check` cannot "
      "see (`include`, `extends`, `volumes_from`, `env_file`, `build`, a `container:NAME` namespace, a variable "
      "from the robot's environment) and sets only namespaced sysctls and no value Docker refuses at `up` (as the "
      "fleet's `compose:` is held to), and has no bare text that YAML 1.2 (Compose v2) "
      "reads as a number (`1e3`) nor a boolean Compose refuses; its .env reads the same in Compose v1 and v2.",
      "Fix the compose template (the fleet file's `templates:` folder, or report a bug in the built-in one).")
def _compose_invalid(ctx: Context, t: Target) -> Iterator[Problem]:
    where = ("templates",) if ctx.spec.templates else ()
    for why in t.env_problems:
        found = re.match(r"line (\d+): ", why)     # compose_env.read_env's
        what, _ = _rendered_at(ctx.spec, t, ".env", "env.j2", None)
        wrote = template_line(str(Path(str(ctx.spec.templates)) / "env.j2"), _content(t, ".env"), int(found[1]),
                              _LF) if found and _overridden(ctx.spec.templates, "env.j2") else None
        why = f"{rendered_line(int(found[1]), '')}: {why[found.end():]}" if found else why
        yield problem_at(ctx.spec, where, f"{what}: {why} ("
                                          f"{f'written by line {wrote} of the template; ' if wrote else ''}"
                                          "fix the .env template)")
    if t.compose_error or not isinstance((t.compose or {}).get("services"), dict):
        why = t.compose_error or "it has no `services:` mapping"
        what, at = _rendered_at(ctx.spec, t, "compose.yml", "compose.yml.j2", t.compose_error_line)
        yield problem_at(ctx.spec, where, (
            f"{what} is not a valid compose file ({why}{f'; at {at}' if at else ''}): fix the compose template"))
        return
    # A compose template's output: the built-in one quotes every string (render.yaml_str, _Dumper).
    numbers = _plain_numbers(t.raw_compose, t.release) if t.release.compose_data is None else []
    if numbers:
        (line, text), more = numbers[0], f" (and {len(numbers) - 1} more)" if len(numbers) > 1 else ""
        what, place = _rendered_at(ctx.spec, t, "compose.yml", "compose.yml.j2", line)
        yield problem_at(ctx.spec, where, (
            f"{what} has {shown(text)} unquoted at {place or 'a line'}{more}: Compose v1 "
            "(YAML 1.1) reads it as text, Compose v2 (YAML 1.2) as a number, and refuses it where text is "
            "required (`hostname`, `extra_hosts` keys); quote it in the compose template"))
    # The fleet's `compose:` refuses these at load (fleet.MANAGED_COMPOSE, _check_compose_conflicts);
    # a user's compose template renders them past it, so the rendered file is judged the same way.
    if "include" in (t.compose or {}):
        yield from _brings_in(ctx, t)
    if t.release.compose_data is None:      # a user's template: the built-in writes real booleans, no ${VAR}
        yield from _unread(ctx, t)
    user = t.release.compose_data is None     # the built-in template writes `compose:` values fleet.py checked
    for name, svc in t.services.items():
        # the built-in template's services have none of these keys: skip them at the cost of a lookup
        if isinstance(svc, dict) and not (_SUSPECT_KEYS.isdisjoint(svc) and
                                          not str(svc.get("network_mode", "")).startswith("container:")):
            yield from _brought_in(ctx, name, svc)
            for keypath, message in _refused_sysctls(name, svc):
                yield _service_problem(ctx.spec, name, keypath, message)
        if user and isinstance(svc, dict) and not _DOCKER_VALUE_KEYS.isdisjoint(svc):
            for keypath, message in _docker_refused(name, svc, t.services):
                yield _service_problem(ctx.spec, name, keypath, message)
    yield from _schema_problems(ctx, t)


def _unread(ctx: Context, t: Target) -> Iterator[Problem]:
    """A user template's values `check` would judge otherwise than the robot's Compose: a boolean
    Compose refuses, and a value that takes a variable from the robot's environment."""
    for name, svc in t.services.items():
        for keypath, what in _not_booleans(name, svc) if isinstance(svc, dict) else ():
            yield _service_problem(ctx.spec, name, keypath, (
                f"service {shown(name)} of {ROBOTS} has {what}, which is not a boolean Compose reads (true/false, "
                "yes/no, y/n, on/off): compose would refuse the file; fix the compose template"))
    for keypath, var in _robot_env_refs(t):
        name = keypath[1] if keypath[0] == "services" and len(keypath) > 1 else ""
        yield _service_problem(ctx.spec, name, ("templates",) if ctx.spec.templates else ("services",), (
            f"the compose.yml rendered for {ROBOTS} has `{'.'.join(map(str, keypath))}`, which depends on "
            f"${{{var}}}: the .env does not set it, so it comes from the robot's environment, which `check` cannot "
            "see; write the value (or set it in the .env template)"))


# Service keys Compose casts to a boolean (compose-go's interpolation casts): check reads them as it does.
_BOOLEAN_KEYS = ("privileged", "read_only", "init", "tty", "stdin_open", "oom_kill_disable")
_TRUE, _FALSE = frozenset({"true", "yes", "y", "on"}), frozenset({"false", "no", "n", "off"})


def compose_bool(value: Any) -> bool | None:
    """`value` as Compose casts it to a boolean (any case of true/yes/y/on, false/no/n/off, as the
    YAML 1.1 words PyYAML reads); None when Compose refuses it ("1", "", "maybe")."""
    if isinstance(value, bool):
        return value
    text = str(value).lower() if isinstance(value, str) else None
    return True if text in _TRUE else False if text in _FALSE else None


def _not_booleans(name: str, svc: Mapping[str, Any]) -> Iterator[tuple[tuple, str]]:
    for key in _BOOLEAN_KEYS:
        if key in svc and compose_bool(svc[key]) is None:
            yield ("services", name, "compose", key), f"`{key}: {svc[key]!r}`"
    for i, entry in enumerate(_as_list(svc.get("volumes"))):
        if isinstance(entry, dict) and "read_only" in entry and compose_bool(entry["read_only"]) is None:
            yield ("services", name, "volumes"), f"`read_only: {entry['read_only']!r}` on volume {i + 1}"


# Service keys whose value from the robot's environment changes nothing `check` judges
_UNJUDGED_KEYS = frozenset({"environment", "labels", "command", "entrypoint", "healthcheck", "container_name",
                            "hostname", "working_dir", "stop_grace_period", "logging", "image"})


def _robot_env_refs(t: Target) -> Iterator[tuple[tuple, str]]:
    """(key path, variable) of each value of a user's compose.yml that takes a variable the .env
    does not set: on the robot, Compose fills it from its own environment (`${HOME}`, `${USER}`)."""
    raw = t.raw_compose or {}
    services = raw.get("services")
    places: list[tuple[tuple, Any]] = [(("services", n, k), v) for n, svc in
                                       (services.items() if isinstance(services, dict) else ())
                                       if isinstance(svc, dict) for k, v in svc.items() if k not in _UNJUDGED_KEYS]
    places += [((k,), raw[k]) for k in ("volumes", "configs", "secrets", "networks") if k in raw]
    for keypath, value in places:
        for text in _texts(value):
            if "$" in text:
                missing: list[str] = []
                substitute(text, t.env, missing)
                if missing:
                    yield keypath, missing[0]
                    break


_SUSPECT_KEYS = frozenset({"extends", "volumes_from", "env_file", "label_file", "build", "pid", "ipc", "sysctls"})
_STR_TAG = "tag:yaml.org,2002:str"


def _plain_numbers(raw: Any, release: RenderedRelease) -> list[tuple[int, str]]:
    """(line, text) of each plain scalar in the compose.yml that PyYAML, as Compose v1, read as
    text and a YAML 1.2 reader takes for a number (files.reads_as_number). Its events, which keep
    a scalar's quoting, are read only when some text of the parsed file could be one."""
    suspects = {text for text in _texts(raw) if reads_as_number(text)}    # ~0.1 ms a robot, a parse ~3 ms
    if not suspects:
        return []
    text = next(f.content for f in release.files if f.name == "compose.yml")
    resolver = yaml.resolver.Resolver()
    return [(event.start_mark.line + 1 if event.start_mark else 0, event.value)
            for event in yaml.parse(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
            if isinstance(event, yaml.ScalarEvent) and event.implicit[0] and event.value in suspects
            and resolver.resolve(yaml.ScalarNode, event.value, (True, False)) == _STR_TAG]


def _texts(value: Any) -> list[str]:
    """Every string of parsed YAML, keys too (a loop, not nested generators: a third of the time)."""
    stack, found = [value], []
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            found.append(item)
        elif isinstance(item, dict):
            stack += item
            stack += item.values()
        elif isinstance(item, list):
            stack += item
    return found


@rule("dds-peers-missing", "error", "release", "The DDS config is valid XML and, off host networking, lists "
      "explicit unicast peers.",
      "Render the peers from the deployed services (built-in templates do), or use `ros.network_mode: host`.")
def _dds_peers(ctx: Context, t: Target) -> Iterator[Problem]:
    name = "cyclonedds.xml" if ctx.spec.rmw == "cyclonedds" else "fastdds.xml"
    where = ("ros", "network_mode")
    xml = next((f.content for f in t.release.files if f.name == name), None)
    if all(svc.get("network_mode") == "host" for svc in t.services.values() if isinstance(svc, dict)):
        # no peers needed, but the robot's DDS loads the profile all the same: a malformed one breaks it
        yield from _dds_unparsable(ctx, t, name, xml)
        return
    if xml is None:
        yield problem_at(ctx.spec, where, f"no {name} was rendered for {ROBOTS}, whose services are not on host "
                                          "networking: DDS discovery needs it; check the templates")
        return
    try:
        peers = dds_peers(xml)
    except ET.ParseError as exc:
        yield _xml_problem(ctx, t, name, exc, where)
        return
    if not peers:
        yield problem_at(ctx.spec, where, (
            f"services of {ROBOTS} are on a bridge network, which carries no multicast, and {name} lists no "
            "unicast peers: nodes would not discover each other; render the peers or use network_mode: host"))


def _dds_unparsable(ctx: Context, t: Target, name: str, xml: str | None) -> Iterator[Problem]:
    try:
        if xml is not None:
            dds_peers(xml)
    except ET.ParseError as exc:
        yield _xml_problem(ctx, t, name, exc, ("templates",) if ctx.spec.templates else ("ros",))


def _xml_problem(ctx: Context, t: Target, name: str, exc: ET.ParseError, where: tuple) -> Problem:
    line = exc.position[0] if getattr(exc, "position", None) else None
    why = re.sub(r": line \d+, column \d+$", "", str(exc))     # said below, as a line of the rendered file
    what, at = _rendered_at(ctx.spec, t, name, f"{name}.j2", line, breaks=_XML_BREAK)
    return problem_at(ctx.spec, where, f"{what} is not valid XML ({why}{f'; at {at}' if at else ''}): fix its template")


@rule("domain-id-not-injected", "error", "release", "ROS_DOMAIN_ID comes from the robot's .env, never hard-coded.",
      "In the compose template write `ROS_DOMAIN_ID: ${ROS_DOMAIN_ID:-0}` and set it in .env.")
def _domain_injected(ctx: Context, t: Target) -> Iterator[Problem]:
    if t.env.get("ROS_DOMAIN_ID") != str(t.host.ros_domain_id):
        yield problem_at(ctx.spec, ("templates",) if ctx.spec.templates else (), (
            f"the .env rendered for {ROBOTS} does not set ROS_DOMAIN_ID to the robot's ros_domain_id: "
            "fix the .env template"))
    services = (t.raw_compose or {}).get("services")
    for name, svc in (services.items() if isinstance(services, dict) else ()):
        raw = env_of(svc).get("ROS_DOMAIN_ID", "") if isinstance(svc, dict) else ""
        if not re.search(r"\$\{?ROS_DOMAIN_ID\b", raw):
            yield problem_at(ctx.spec, ("services", name), (
                f"service {shown(name)} of {ROBOTS} does not take ROS_DOMAIN_ID from .env (`${{ROS_DOMAIN_ID}}`): "
                "a hard-coded or missing ID puts robots on the wrong domain; fix the compose template"))


# ------------------------------------------------- a service of a release

Finding = Iterator[tuple[tuple, str]]   # (key path in the fleet file, message)


# ------------------------------------------------- a user template's host files (template_output.py)

# (template, rendered file): installed as root by hostchanges-root.sh, where cron, logrotate and udev run them.
_HOST_TEMPLATES = (("logrotate.cron.j2", "logrotate.cron"), ("logrotate.conf.j2", "logrotate.conf"),
                   ("udev.rules.j2", "99-rosdeploy.rules"))


@functools.lru_cache(maxsize=64)
def _overridden(templates: str | None, name: str) -> bool:
    """Whether the fleet's `templates:` folder replaces the built-in template `name` (once per process)."""
    return bool(templates) and (Path(str(templates)) / name).is_file()


@rule("host-template-root", "error", "release",
      "A user template's udev rules, logrotate.conf and logrotate.cron, which are installed as root, do only what "
      "the built-in ones do: no program runs, no path outside the project's logs.",
      "Remove the line from the template in the fleet file's `templates:` folder (or delete the override); give "
      "other root jobs to your provisioning.")
def _host_template_root(ctx: Context, t: Target) -> Iterator[Problem]:
    if not ctx.spec.templates:
        return      # the built-in templates wrote every file
    from rosdeploy import template_output
    files = {f.name: f.content for f in t.release.files}
    for template, name in _HOST_TEMPLATES:
        if name not in files or not _overridden(ctx.spec.templates, template):
            continue     # the built-in template's output: nothing to read back
        if name == "99-rosdeploy.rules":
            from rosdeploy.hostchanges import RULES_DIR, rules_name
            found = template_output.udev_findings(files[name], f"{RULES_DIR}/{rules_name(ctx.spec.project)}")
        else:
            expected = template_output.rotation_for(ctx.spec, t.host)
            read = template_output.cron_findings if name == "logrotate.cron" else template_output.logrotate_findings
            found = read(files[name], expected)
        source = Path(str(ctx.spec.templates)) / template
        for finding in found:
            yield problem_at(ctx.spec, ("templates",), f"{finding.message} (the {name} rendered for {ROBOTS} from "
                                                       f"your template {source})")


def _schema_problems(ctx: Context, t: Target) -> Iterator[Problem]:
    """compose-invalid, for a compose template's output: the Compose schema, as fleet.py holds `compose:` to it.
    A key only v1 refuses (`gpus`, top-level `name`) is let through: Compose v2 reads it."""
    if t.release.compose_data is not None or t.compose is None:
        return     # the built-in template writes from checked data; an unparsable file is said above
    from rosdeploy.template_output import compose_schema_findings
    for finding in compose_schema_findings(t.compose):
        if finding.v2_accepts or finding.path[-1:] in (("privileged",), ("read_only",)):
            continue     # v2 reads it; or the boolean reading of _privileges/_writable says it already
        at = ".".join(map(str, finding.path)) or "the top level"
        yield problem_at(ctx.spec, ("templates",) if ctx.spec.templates else (), (
            f"the compose.yml rendered for {ROBOTS} breaks the Compose schema at {at}: {finding.message}; Compose "
            "refuses the file at `up` on every robot: fix the compose template"))


@rule("image-unversioned", "error", "service", "Every image carries an explicit version tag or digest, never `latest`.",
      "Set `version:` (or the service's `tag:`) and keep the tag in the compose template.")
def _image_unversioned(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    image = str(svc.get("image") or "")
    if "@sha256:" in image:
        return
    last = image.rsplit("/", 1)[-1]
    tag = last.rpartition(":")[2] if ":" in last else ""
    if not tag or tag.lower() == "latest":
        yield ("services", name, "image"), (
            f"service {shown(name)} of {ROBOTS} would run image `{image or '(none)'}`, which has no version "
            "tag (or `latest`): it cannot be rolled back to; keep `:<version>` in the compose template")


@rule("healthcheck-missing", "warning", "service", "Every service has a health check that proves the node works.",
      "Add `healthcheck: {test: [CMD-SHELL, ...]}` or `healthcheck: image` if the image has a HEALTHCHECK.")
def _healthcheck_missing(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    check = svc.get("healthcheck")
    declared = ctx.service(name)
    if declared is not None and declared.healthcheck_from_image:
        return
    test = check.get("test") if isinstance(check, dict) else None
    if not isinstance(check, dict) or compose_bool(check.get("disable", False)) is not False or \
            test in (["NONE"], "NONE", None):
        yield ("services", name, "healthcheck"), (
            f"service {shown(name)} has no health check: a crashed-but-running node looks healthy to the deploy gate "
            "and to depends_on; add `healthcheck:` (or `healthcheck: image` to trust the image's HEALTHCHECK)")


@rule("restart-missing", "error", "service", "Every service has a restart policy.",
      "Set `restart: unless-stopped` (always for critical drivers and watchdogs).")
def _restart_missing(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    restart = str(svc.get("restart", "no"))
    if restart not in ("always", "unless-stopped") and not restart.startswith("on-failure"):
        yield ("services", name, "restart"), (
            f"service {shown(name)} of {ROBOTS} has restart policy `{restart}` in the rendered compose.yml: "
            "it stays down after a crash or reboot; set `restart: unless-stopped` (or always)")


@rule("compose-ref-undefined", "error", "service",
      "A service's `secrets:`/`configs:` (passed through `compose:`) name ones the compose.yml defines.",
      "Hand a vault value over with the service's fleet key `secrets: {ENV: vault_var}` (written to .env), "
      "a file with `files:`; or define it at the top level of your compose template.")
def _compose_ref_undefined(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    """Compose refuses the whole file at `up` (`service refers to undefined secret`), on the robot,
    mid-deploy. The built-in template defines no top-level secrets or configs; a user's may."""
    for kind, instead in (("secrets", "the service's fleet key `secrets: {ENV: vault_var}` (written to the "
                                      "robot's .env)"), ("configs", "the fleet key `files:`")):
        defined = _dig(t.compose, kind)
        for i, entry in enumerate(_as_list(svc.get(kind))):
            source = entry.get("source") if isinstance(entry, dict) else entry
            if not isinstance(source, str) or source not in defined:
                yield ("services", name, "compose", kind, i), (
                    f"service {shown(name)} of {ROBOTS} uses {kind[:-1]} {shown(source)}, which the compose.yml does "
                    f"not define at the top level (compose would refuse the file): use {instead} instead")


def _brings_in(ctx: Context, t: Target) -> Iterator[Problem]:
    """A top-level `include:`: compose would merge in a file from the robot's disk, which no rule
    checked (it can hold `privileged: true`, `/:/host`)."""
    if (t.compose or {}).get("include"):
        where = ("templates",) if ctx.spec.templates else ("services",)
        yield _service_problem(ctx.spec, "", where, (
            f"the compose.yml rendered for {ROBOTS} has a top-level `include:`: compose would merge in a compose "
            "file from the robot's disk, which `check` never sees; write its services in the template itself"))


def _brought_in(ctx: Context, name: str, svc: Mapping[str, Any]) -> Iterator[Problem]:
    for key, what in _outside_keys(svc):
        yield _service_problem(ctx.spec, name, ("services", name, "compose", key), (
            f"service {shown(name)} of {ROBOTS} has `{key}` in the rendered compose.yml: it brings in {what}, which "
            "`check` never sees; write the service's own keys instead"))


def _outside_keys(svc: Mapping[str, Any]) -> Iterator[tuple[str, str]]:
    """(compose key, what it brings in) of a service's keys that reach outside the compose file."""
    extends = svc.get("extends")
    if isinstance(extends, dict) and extends.get("file"):
        yield "extends", f"a service from another compose file ({shown(str(extends['file']))})"
    elif extends is not None:       # compose merges the other service's keys in, after `check` has judged this one
        other = extends.get("service") if isinstance(extends, dict) else extends
        yield "extends", f"the keys of service {shown(str(other))}, merged in as compose resolves it"
    if svc.get("volumes_from"):
        yield "volumes_from", "another container's mounts"
    if svc.get("env_file"):
        yield "env_file", "environment from a file on the robot (set `environment:` or `secrets:`)"
    if svc.get("label_file"):     # Compose v2's: labels rosdeploy renders (io.rosdeploy.*) from a file
        yield "label_file", "labels from a file on the robot (write `labels:`)"
    if svc.get("build"):     # `up` builds it where the image is not pulled: not the version `check` judged
        yield "build", "an image built on the robot from its own folder (run the registry's image: `image:`)"
    for key in ("pid", "ipc", "network_mode"):
        if str(svc.get(key, "")).startswith("container:"):
            yield key, f"the namespace of a container outside the project ({shown(str(svc[key]))})"


def _refused_sysctls(name: str, svc: Mapping[str, Any]) -> Finding:
    """Sysctls runc or Docker refuse for this service, as fleet._check_compose_conflicts judges the
    fleet's `compose: {sysctls}`: else every robot fails at `up`."""
    host_net, ipc_host = svc.get("network_mode") == "host", svc.get("ipc") == "host"
    for at, sysctl in sysctl_names(svc.get("sysctls")):
        why = _SYSCTL_REFUSED.get(sysctl_refusal(sysctl, host_net, ipc_host))
        if why:
            yield ("services", name, "compose", "sysctls", at), (
                f"service {shown(name)} of {ROBOTS} sets sysctl {shown(sysctl)}, which {why}; set it on the robot")


# The service keys fleet._check_compose_values and _check_compose_formats judge (what Docker or
# Compose refuses at `up` though the schema lets it through), and `ipc`/`pid: service:NAME`.
_DOCKER_VALUE_KEYS = frozenset({"working_dir", "dns", "isolation", "pid", "userns_mode", "ipc", "storage_opt",
                                "stop_signal", "ulimits", "mem_swappiness", "stop_grace_period", "ports", "expose",
                                "extra_hosts", "cpuset", "blkio_config", "cgroup"})


class _Said:
    """What fleet.py's compose value checks say, collected: the one method of their Reader they call."""

    def __init__(self) -> None:
        self.said: list[tuple[tuple, str]] = []

    def error(self, kp: tuple, message: str) -> None:
        self.said.append((kp, message))


def _docker_refused(name: str, svc: Mapping[str, Any], services: Mapping[str, Any]) -> Finding:
    """A user template's service values Docker or Compose refuses at `up` on every robot, as fleet.py
    judges the fleet's `compose:` keys (README: "what Docker refuses at the robot is refused here")."""
    values = {k: svc[k] for k in _DOCKER_VALUE_KEYS if k in svc}
    for kp, why in _value_refusals(repr(values), values):
        at = ".".join(map(str, kp))
        yield ("services", name, "compose", *kp), (
            f"service {shown(name)} of {ROBOTS} has `{at}` in the rendered compose.yml, which Docker or Compose "
            f"refuses at `up`: {why}; fix the compose template")
    cgroup = svc.get("cgroup")     # Compose v2's key: the v1 schema of _schema_problems lets any value pass
    if cgroup is not None and cgroup not in ("host", "private"):
        yield ("services", name, "compose", "cgroup"), (
            f"service {shown(name)} of {ROBOTS} has `cgroup: {cgroup!r}` in the rendered compose.yml: Compose takes "
            "only `host` or `private` (lower case) and refuses the file; fix the compose template")
    for key in ("ipc", "pid"):
        shared = svc.get(key)
        target = shared[len("service:"):] if isinstance(shared, str) and shared.startswith("service:") else None
        if target is not None and (target == name or target not in services):
            why = f"its own {key} namespace (a cycle)" if target == name else f"{key}: no service is named `{target}`"
            yield ("services", name, "compose", key), (
                f"service {shown(name)} of {ROBOTS} shares {why} in the rendered compose.yml: Compose refuses the "
                "file; fix the compose template")


# fleet.py's findings by the repr of the values: lru_cache cannot key on a service's lists and mappings
_REFUSALS: dict[str, tuple[tuple[tuple, str], ...]] = {}


def _value_refusals(written: str, values: dict) -> tuple[tuple[tuple, str], ...]:
    """fleet.py's findings on `values`, by their repr (`written`): a fleet's robots share them."""
    found = _REFUSALS.get(written)
    if found is None:
        from rosdeploy.fleet import _check_compose_formats, _check_compose_values
        said = _Said()
        try:
            _check_compose_values(cast(Any, said), (), values)
            _check_compose_formats(cast(Any, said), (), values)
        except (AttributeError, TypeError, KeyError, ValueError):
            # a shape the fleet file's schema check refuses before these run (`blkio_config: {1: []}`):
            # here _schema_problems names it; these value checks assume the schema's shapes
            said.said.clear()
        if len(_REFUSALS) > 4096:
            _REFUSALS.clear()
        found = _REFUSALS[written] = tuple(said.said)
    return found


_SYSCTL_REFUSED = {
    "kernel": "is not a namespaced sysctl: runc refuses to set the robot's kernel from a container",
    "host-net": "needs the container's own network namespace: Docker refuses it on host networking",
    "ipc-host": "needs the container's own IPC namespace: Docker refuses it with `ipc: host`",
}


@rule("log-rotation-missing", "error", "service", "Every service's logs rotate (json-file max-size and max-file).",
      "Keep `logging: {driver: json-file, options: {max-size, max-file}}` in the compose template.")
def _log_rotation(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    logging = _dig(svc, "logging")
    driver = logging.get("driver", "json-file")
    options = _dig(logging, "options")
    if driver in ROTATING_LOG_DRIVERS:
        return
    if driver != "json-file" or "max-size" not in options or "max-file" not in options:
        yield ("logging",), (
            f"service {shown(name)} of {ROBOTS} logs with `{driver}` without max-size/max-file: ROS logs can fill the "
            "robot's disk; render `logging: {driver: json-file, options: {max-size: 10m, max-file: \"3\"}}`")


@rule("privileged", "error", "service", "No privileged container unless declared on purpose.",
      "Map the devices with `devices:` instead; if it must be privileged, add `allow_privileged: true`.")
def _privileged(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    declared = ctx.service(name)
    if declared and declared.allow_privileged:
        return
    for key, what in _privileges(svc):
        yield ("services", name, key), (
            f"service {shown(name)} {what}: it can do anything to the robot; map devices with `devices:` "
            "instead (their groups are added for you), or set `allow_privileged: true` to say it is on purpose")


# Capabilities that are root on the host in all but name (mount, load modules, raw I/O, read any file)
_ROOT_CAPS = frozenset({"ALL", "SYS_ADMIN", "SYS_MODULE", "SYS_RAWIO", "SYS_PTRACE", "DAC_READ_SEARCH", "SYS_BOOT"})


def _privileges(svc: dict) -> Iterator[tuple[str, str]]:
    """(compose key, what it grants) for each way a service config is privileged: `privileged:`
    itself and the keys that amount to it piece by piece."""
    if compose_bool(svc.get("privileged")):
        yield "privileged", "runs privileged"
    for key in ("pid", "userns_mode"):
        if svc.get(key) == "host":
            yield key, f"shares the robot's {'processes' if key == 'pid' else 'user namespace'} ({key}: host)"
    caps = sorted({str(c).upper().removeprefix("CAP_") for c in _as_list(svc.get("cap_add"))} & _ROOT_CAPS)
    if caps:
        yield "cap_add", f"adds {', '.join(caps)}"
    loose = [str(o) for o in _as_list(svc.get("security_opt"))
             if re.search(r"unconfined|label[:=]disable", str(o))]
    if loose:
        yield "security_opt", f"turns off confinement ({', '.join(loose)})"
    rules = [str(r) for r in _as_list(svc.get("device_cgroup_rules")) if _root_device_rule(str(r))]
    if rules:
        what = "every device" if any(r.strip().startswith("a") for r in rules) else "devices that are root"
        yield "device_cgroup_rules", (f"may use {what} of the robot (device_cgroup_rules "
                                      f"{', '.join(repr(r) for r in rules[:3])})")


# device_cgroup_rules as Docker parses them: type, major:minor, access.
_DEVICE_RULE = re.compile(r"([abc]) +([0-9]+|\*):([0-9]+|\*) +([rwm]{1,3})")
# Character devices that are root in all but name, by (major, minor); minor None is every minor.
# mem, kmem, port (1:1, 1:2, 1:4) read and write physical memory and I/O ports; SCSI generic (21)
# sends raw commands to disks; device-mapper and loop control (10:236, 10:237) create block devices
# and the microcode loader (10:184) rewrites the CPU's. Other majors with a wildcard minor are the
# usual robot rules (ttyUSB 188, ttyACM 166, USB 189, video 81), but 1 and 10 hold the above.
_ROOT_CHAR_DEVICES = {(1, 1), (1, 2), (1, 4), (21, None), (10, 184), (10, 236), (10, 237)}


def _root_device_rule(rule: str) -> bool:
    """Does this cgroup rule let the container (which has CAP_MKNOD by default) reach a device that
    is root on the robot? `a` is every device; `b` is block devices, i.e. the disks themselves; `c`
    with a wildcard major is every character device. An unparsable rule counts: Docker refuses it, and
    what it would grant cannot be told."""
    found = _DEVICE_RULE.fullmatch(rule.strip())
    if not found:
        return True
    kind, major, minor = found[1], found[2], found[3]
    if kind in "ab" or major == "*":
        return True
    if minor == "*":
        return int(major) in {m for m, _ in _ROOT_CHAR_DEVICES}
    return (int(major), None) in _ROOT_CHAR_DEVICES or (int(major), int(minor)) in _ROOT_CHAR_DEVICES


@rule("docker-socket-mounted", "error", "service", "No container mounts the Docker socket.",
      "Remove the mount; a container that needs the engine is root on the robot. Add "
      "`allow_privileged: true` if it is on purpose.")
def _docker_socket(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    declared = ctx.service(name)
    if declared and declared.allow_privileged:
        return
    mounts = sorted((path, written) for written, path, _ in _service_mounts(ctx, t, name, svc))
    socket = next(((path, written) for path, written in mounts if _holds_engine_socket(path)), None)
    if socket:
        path = socket[0]
        yield ("services", name, "volumes"), (
            f"service {shown(name)} mounts {_shown_mount(*socket)}"
            f"{'' if path.endswith('.sock') else ', which holds the engine socket'}"
            ": whoever controls the container controls the robot's container engine, which is root on the robot; "
            "remove the mount, or set `allow_privileged: true` to say it is on purpose")


_ENGINE_SOCKETS = ("/var/run/docker.sock", "/run/docker.sock", "/run/containerd/containerd.sock",
                   "/var/run/containerd/containerd.sock", "/run/podman/podman.sock", "/var/run/podman/podman.sock")


@functools.lru_cache(maxsize=1024)    # pure, and a fleet's robots share their mounts: once per path
def _holds_engine_socket(source: str) -> bool:
    """An engine's socket, or a directory it lies in (`/var/run:/hostrun` reaches it as well)."""
    if source.rstrip("/").rsplit("/", 1)[-1] in ("docker.sock", "containerd.sock", "podman.sock"):
        return True
    folder = "/" + source.strip("/")
    return source.startswith("/") and any(sock.startswith(folder.rstrip("/") + "/") for sock in _ENGINE_SOCKETS)


@rule("device-root", "error", "service", "No container maps a device that is root on the robot, nor mounts a disk "
      "through a named volume (`driver_opts: {type: ext4, device: /dev/sda1}`).",
      "Map only the device the node needs (a serial port, a camera); add `allow_privileged: true` if it is on "
      "purpose.")
def _device_root(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    for _, path in _unwaived_sources(ctx, name, svc, "devices"):
        what = _root_device(path)
        if what:
            yield ("services", name, "devices"), (
                f"service {shown(name)} maps {path} on {ROBOTS}, {what}: whoever controls the container is root on the "
                "robot; map only the device the node needs, or set `allow_privileged: true` to say it is on purpose")
    disks = t.disk_volumes     # {} for the built-in template's output: nothing more per service
    for entry, source in _unwaived_sources(ctx, name, svc, "volumes") if disks else ():
        if source in disks and (not isinstance(entry, dict) or entry.get("type", "volume") == "volume"):
            device, kind, read_only = disks[source]
            writes = _writable(entry) and not read_only
            yield ("services", name, "volumes"), (
                f"service {shown(name)} mounts volume {shown(source)}, which the engine mounts from {device}"
                f"{f' as {shown(kind)}' if kind else ''} on {ROBOTS}, which is a disk (every file on it, /etc/shadow "
                f"included, can be {'rewritten' if writes else 'read'}): whoever controls the container "
                f"{'is root on' if writes else 'reads every secret of'} the robot; mount only the folder the node "
                "needs, or set `allow_privileged: true` to say it is on purpose")


def _unwaived_sources(ctx: Context, name: str, svc: dict, key: str) -> Iterator[tuple[Any, str]]:
    """(entry, robot path as the kernel reads it) of a service's `devices` or `volumes`; none when
    the service says it is privileged on purpose (allow_privileged waives these rules too)."""
    declared = ctx.service(name)
    if declared and declared.allow_privileged:
        return
    for entry in _as_list(svc.get(key)):
        yield entry, _normal_path(_mount_source(entry))


# Device nodes that are root in all but name (the same ones as _ROOT_CHAR_DEVICES): physical memory,
# I/O ports, the microcode loader, device-mapper and loop control; and the disks, whose every file
# (/etc/shadow, /root/.ssh) a container that writes the block device can rewrite.
_ROOT_DEVICES = ("/dev/mem", "/dev/kmem", "/dev/port", "/dev/cpu/microcode", "/dev/mapper/control",
                 "/dev/loop-control")
# Disks by kernel name, and the udev links to them (/dev/disk/by-uuid/..., /dev/block/8:1,
# /dev/root): the same disk under another name. mtd*/ubi* are the raw flash of embedded boards.
_DISK = re.compile(r"/dev/(?:(?:sd|hd|vd|xvd)[a-z]|nvme[0-9]|mmcblk[0-9]|sg[0-9]|loop[0-9]|dm-[0-9]|md[0-9]|mapper/"
                   r"|nbd[0-9]|zram[0-9]|ram[0-9]|mtd[0-9]|mtdblock[0-9]|ubi[0-9]|ubiblock[0-9]|disk(?:/|$)"
                   r"|block(?:/|$)|root$)")


@functools.lru_cache(maxsize=1024)    # pure, and a fleet's robots share their mounts: once per path
def _root_device(path: str) -> str:
    """Why mapping `path` (normalised) is root on the robot, or "" when it is not."""
    if path == "/dev":
        return "which is every device of the robot (Docker maps all the devices under a folder)"
    if path in _ROOT_DEVICES:
        return "which reads and writes the robot's memory or kernel" if path != "/dev/loop-control" else \
            "which makes block devices"
    if any(device.startswith(path + "/") for device in _ROOT_DEVICES):
        return f"a folder that holds {next(d for d in _ROOT_DEVICES if d.startswith(path + '/'))}"
    if _DISK.match(path):
        return "which is a disk (every file on it, /etc/shadow included, can be rewritten)"
    return ""


@functools.lru_cache(maxsize=1024)    # pure, and a fleet's robots share their mounts: once per path
def _normal_path(path: str) -> str:
    """`path` as the kernel reads it: `/dev//`, `/etc/./` and `//etc` are /dev and /etc."""
    if not path.startswith("/"):
        return path
    return "/" + posixpath.normpath(path).lstrip("/")


@rule("mount-system-writable", "error", "service", "No container mounts a robot's system folder writable.",
      "Mount it read-only (`:ro`), or only the folder the node needs; add `allow_privileged: true` if it is on "
      "purpose.")
def _mount_system_writable(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    declared = ctx.service(name)
    if declared and declared.allow_privileged:
        return
    robot = _robot_of(ctx.spec, t)
    for written, source, writable in _service_mounts(ctx, t, name, svc):
        folder = _root_folder(source, robot) if writable else ""
        # the engine's socket folders (/, /var, /run) are docker-socket-mounted's finding
        if folder and not _holds_engine_socket(source):
            yield ("services", name, "volumes"), (
                f"service {shown(name)} mounts {_shown_mount(source, written)} writable{_holds(source, folder)}: a "
                f"container that writes {folder} is root on the robot; mount it `:ro`, or set "
                "`allow_privileged: true` to say it is on purpose")


# Robot folders a container that writes them is root through: the system's configuration (sudoers,
# passwd, cron, systemd units), root's home, the boot files and kernel modules, the programs root
# runs, the kernel's own settings (/proc/sys/kernel/core_pattern and /sys/kernel/uevent_helper run a
# program as root), and the engines' data (a container's files, its config). Of /sys, only the
# kernel's settings, modules, firmware, cgroups (release_agent) and power (resume= loads a hibernated
# kernel from any device); /sys itself holds them all. /sys/class/gpio or /sys/bus/iio are the robot's
# hardware, which robot containers do mount. Of /home, the folder itself, a user's home and its
# dot files (~/.ssh/authorized_keys, ~/.bashrc: the deploy user runs docker, so is root): a data
# folder in a home (/home/ros/maps) is what robot containers mount.
_SYSTEM_FOLDERS = ("/etc", "/root", "/boot", "/proc", "/sys/kernel", "/sys/module", "/sys/fs", "/sys/firmware",
                   "/sys/power", "/usr", "/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32", "/var/lib/docker",
                   "/var/lib/containerd", "/var/spool/cron", "/home")
# Files of /etc that robot containers commonly mount, and whose content gives nobody root
_HARMLESS = frozenset({"/etc/localtime", "/etc/timezone", "/etc/machine-id", "/etc/hostname", "/etc/os-release",
                       "/etc/lsb-release", "/etc/nv_tegra_release"})


@dataclass(frozen=True)
class _Robot:
    """The robot's folders a compose mount source is read against: compose takes `~` for the SSH
    user's home and a relative path from the release folder (<deploy_root>/<project>/releases/<id>)."""

    home: str       # the SSH user's home, as render reads it for logrotate (rosdeploy_home, else a guess)
    root: str       # the deploy root, absolute
    project: str    # <root>/<project>: its logs and store are the release's own
    release: str    # <project>/releases/<id>, with an id no other release has


def _robot_of(spec: FleetSpec, t: Target) -> _Robot:
    home, root = t.folder_vars
    return _robot_folders(root or spec.deploy_root, home or str(spec.vars.get("rosdeploy_home") or ""), t.host.user,
                          spec.project)


@functools.lru_cache(maxsize=256)     # pure, and a fleet's robots share their user and deploy root
def _robot_folders(root: str, home: str, user: str | None, project: str) -> _Robot:
    # Without ansible_user the SSH user is ssh's own choice: a home of its own, not root's, lest
    # `~/maps` read as a folder in /root (a system folder).
    home = _normal_path("/" + (home or ("root" if user == "root" else f"home/{user or '<ssh user>'}")).lstrip("/"))
    if root == "~" or root.startswith("~/"):
        root = home + root[1:]
    root = _normal_path(root)
    return _Robot(home, root, f"{root}/{project}", f"{root}/{project}/releases/<this release>")


def _service_mounts(ctx: Context, t: Target, name: str, svc: dict) -> tuple[tuple[str, str, bool], ...]:
    found = t.mounts.get(name)
    if found is None:
        found = t.mounts[name] = tuple(_robot_mounts(ctx.spec, t, svc))
    return found


def _robot_mounts(spec: FleetSpec, t: Target, svc: dict) -> Iterator[tuple[str, str, bool]]:
    """(source as written, path on the robot, writable) of each of a service's volumes that takes a
    robot path: a bind mount (absolute, under `~`, or relative to the release folder) or a named
    volume the local driver binds (its `device`). Other named volumes are the engine's own."""
    robot = _robot_of(spec, t)
    binds = t.bind_volumes
    for entry in _as_list(svc.get("volumes")):
        found = _short_mount(entry, robot.home, robot.release) if isinstance(entry, str) else None
        if found:
            yield found
            continue
        written = _mount_source(entry)
        if written.startswith(("/", ".", "~")) or (isinstance(entry, dict) and entry.get("type") == "bind"):
            yield written, _robot_path(written, robot.home, robot.release), _bind_writable(entry)
        elif written in binds:
            device, read_only = binds[written]
            yield written, _robot_path(device, robot.home, robot.release), not read_only and _writable(entry)
    for source in _file_refs(t, svc):     # outside swarm, a config's or secret's `file:` is a read-only bind
        yield source, _robot_path(source, robot.home, robot.release), False


def _file_refs(t: Target, svc: Mapping[str, Any]) -> Iterator[str]:
    """The `file:` of each top-level config or secret the service uses."""
    for kind in ("configs", "secrets"):
        entries = _as_list(svc.get(kind))
        defined = _dig(t.compose, kind) if entries else {}
        for entry in entries:
            source = entry.get("source") if isinstance(entry, dict) else entry
            found = defined.get(source) if isinstance(source, str) else None
            if isinstance(found, dict) and isinstance(found.get("file"), str):
                yield found["file"]


@functools.lru_cache(maxsize=4096)    # pure, and a fleet's robots share their mounts: once per entry
def _short_mount(entry: str, home: str, release: str) -> tuple[str, str, bool] | None:
    """_robot_mounts' answer for a short-syntax bind mount ("src:dst[:ro]"); None for a named volume."""
    written = _mount_source(entry)
    if not written.startswith(("/", ".", "~")):
        return None
    return written, _robot_path(written, home, release), _bind_writable(entry)


@functools.lru_cache(maxsize=4096)    # pure, and a fleet's robots share their mounts: once per path
def _robot_path(source: str, home: str, release: str) -> str:
    """A bind mount's source as compose reads it on the robot: `~` is the SSH user's home (`~x`
    too: compose joins what follows), any other relative path is from the release folder."""
    if source.startswith("~"):
        source = f"{home}/{source[1:]}"
    elif not source.startswith("/"):
        source = f"{release}/{source}"
    return _normal_path(source)


def _shown_mount(path: str, written: str) -> str:
    return path if written == path else f"{written} ({path} on the robot)"


@functools.lru_cache(maxsize=4096)    # pure, and a fleet's robots share their mounts: once per path
def _root_folder(path: str, robot: _Robot) -> str:
    """The folder writing `path` is root through (a system folder, the deploy user's home or deploy
    root); "" for any other, and for the project's logs and store, which the built-in template
    mounts (../../logs/<service>) and which give nobody root."""
    if any(path == own or path.startswith(own + "/") for own in (f"{robot.project}/logs", f"{robot.project}/store")):
        return ""
    return _system_folder(path) or _deploy_folder(path, robot.home, robot.root)


@functools.lru_cache(maxsize=1024)    # pure, and a fleet's robots share their mounts: once per path
def _deploy_folder(path: str, home: str, root: str) -> str:
    """The deploy user's folder a writable mount of `path` writes: its home or a dot file in it
    (~/.ssh/authorized_keys), or the deploy root (the releases, their compose files and the guard,
    which the robot runs as root); "" for any other path (the logs and store: see _root_folder)."""
    for folder in (root, home):
        if _is_or_holds(path, folder):
            return folder
    if path.startswith(root + "/"):
        return root
    return _dot_file(path, home)


@functools.lru_cache(maxsize=1024)    # pure, and a fleet's robots share their mounts: once per path
def _system_folder(source: str) -> str:
    """The system folder `source` is, lies in or holds; "" for any other path."""
    if not source.startswith("/") or source in _HARMLESS:
        return ""     # a named volume, the time zone
    for folder in _SYSTEM_FOLDERS:
        if _is_or_holds(source, folder):
            return folder
        if source.startswith(folder + "/"):
            if folder != "/home":
                return folder
            user, _, inside = source[len("/home/"):].partition("/")
            found = _dot_file(source, f"/home/{user}") if inside else f"/home/{user}"   # a home, ~/.ssh, ~/.bashrc
            if found:
                return found
    return ""


def _is_or_holds(path: str, folder: str) -> bool:
    return path == folder or folder.startswith(path.rstrip("/") + "/")


def _dot_file(path: str, home: str) -> str:
    """The dot file or folder of `home` (~/.ssh, ~/.bashrc) that `path` is or lies in; "" for any other."""
    inside = path[len(home) + 1:] if path.startswith(home + "/") else ""
    return f"{home}/{inside.split('/')[0]}" if inside.startswith(".") else ""


def _holds(source: str, folder: str) -> str:
    return f", which holds {folder}" if folder.startswith(source.rstrip("/") + "/") else ""


def _writable(entry: Any) -> bool:
    """A service's mount without read-only (`name:dst:ro` or the long form's read_only)."""
    if isinstance(entry, dict):
        return not compose_bool(entry.get("read_only", False))
    parts = str(entry).split(":")
    return len(parts) > 1 and "ro" not in (parts[2].split(",") if len(parts) > 2 else ())


def _bind_writable(entry: Any) -> bool:
    """A bind mount from a robot path, without read-only (`src:dst:ro` or the long form's read_only)."""
    if isinstance(entry, dict):
        return entry.get("type", "bind") == "bind" and not compose_bool(entry.get("read_only", False))
    parts = str(entry).split(":")
    return len(parts) > 1 and "ro" not in (parts[2].split(",") if len(parts) > 2 else ())


@rule("shm-too-small", "error", "service", "shm_size is at least 256 MB (Docker's 64 MB breaks DDS shared memory).",
      "Set `ros.shm_size: 512m` (or share the host's with ipc: host).")
def _shm_too_small(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    if _shares_ipc(svc):
        return
    size = _size_or_none(svc.get("shm_size", "64m"))
    if size is None or size < 256 * MB:
        yield ("ros", "shm_size"), (
            f"service {shown(name)} of {ROBOTS} gets {svc.get('shm_size', '64m (the Docker default)')} of /dev/shm: "
            "DDS shared-memory transport needs at least 256 MB; set `ros.shm_size: 512m`")


@rule("shm-small-for-images", "warning", "service", "shm_size is at least 512 MB for services with image topics.",
      "Set `ros.shm_size: 512m` or more.")
def _shm_small_for_images(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    declared = ctx.service(name)
    image_topics = [tp.name for tp in (declared.topics if declared else ()) if IMAGE_TOPIC_RE.search(tp.name)]
    size = _size_or_none(svc.get("shm_size", "64m"))
    if image_topics and not _shares_ipc(svc) and size is not None and 256 * MB <= size < 512 * MB:
        yield ("services", name, "topics"), (
            f"service {shown(name)} publishes image topics ({', '.join(image_topics)}) with only "
            f"{svc.get('shm_size')} of /dev/shm: set `ros.shm_size: 512m` or more")


def _shares_ipc(svc: Mapping[str, Any]) -> bool:
    """The container uses another /dev/shm (the host's or a peer's): its own shm_size does not matter."""
    ipc = str(svc.get("ipc", ""))
    mounts = {_mount_target(v) for v in _as_list(svc.get("volumes"))}
    return ipc == "host" or ipc.startswith(("service:", "container:")) or "/dev/shm" in mounts


def _mount_source(entry: Any) -> str:
    """What a compose volume or device mapping takes from the robot, in its short or long form."""
    return str(entry.get("source", "") if isinstance(entry, dict) else entry).split(":")[0]


def _mount_target(volume: Any) -> str:
    """Where a compose volume lands in the container, in its short ("src:dst[:ro]") or long form."""
    if isinstance(volume, dict):
        return str(volume.get("target", ""))
    parts = str(volume).split(":")
    return parts[1] if len(parts) > 1 else parts[0]


@rule("device-unstable", "warning", "service", "Devices are mapped by stable udev names (/dev/robot/*).",
      "Add a udev entry in the inventory (`udev:`) and map /dev/robot/<name> instead of /dev/ttyUSB0.")
def _device_unstable(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    for entry in _as_list(svc.get("devices")):
        path = _mount_source(entry)
        if not path.startswith(STABLE_DEVICE_PREFIXES):
            yield ("services", name, "devices"), (
                f"service {shown(name)} maps {path} on {ROBOTS}: names like /dev/ttyUSB0 change with USB enumeration "
                "order across boots; give the device a udev symlink (inventory `udev:`) and use /dev/robot/<name>")


@rule("resources-missing", "warning", "service", "Every service has memory and CPU limits.",
      "Set `resources: {memory: 512m, cpus: 1.0}`.")
def _resources_missing(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    limits = _dig(svc, "deploy", "resources", "limits")
    missing = [what for what, keys in (("memory", ("mem_limit", "memory")), ("CPU", ("cpus",)))
               if not any(k in svc or k in limits for k in keys)]
    if missing:
        yield ("services", name, "resources"), (
            f"service {shown(name)} has no {' or '.join(missing)} limit: one runaway node can starve the "
            "rest of the robot; set `resources: {memory: 512m, cpus: 1.0}`")


@rule("user-root", "warning", "service", "Containers run as a non-root user.",
      "Set `user: \"1000:1000\"`; the groups of mapped devices (dialout, video) are added for you.")
def _user_root(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    user = str(svc.get("user", "")).split(":")[0]
    if user in ("root", "0"):
        yield ("services", name, "user"), (
            f"service {shown(name)} runs as root: set a non-root `user:` such as \"1000:1000\" "
            "(device groups are added from `devices:`)")


@rule("user-unset", "info", "service", "A container user is set explicitly.",
      "Set `user:` unless the image already runs as a non-root USER.")
def _user_unset(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    if "user" not in svc:
        yield ("services", name), (
            f"service {shown(name)} sets no `user:`: it runs as the image's USER, root unless the image says "
            "otherwise; set `user:` or make sure the image is non-root")


@rule("gpu-reservation", "error", "service", "A GPU is reserved exactly for gpu services on robots with `gpu: true`.",
      "Keep the nvidia device reservation in the compose template, conditioned on the robot's gpu.")
def _gpu_reservation(ctx: Context, t: Target, name: str, svc: dict) -> Finding:
    declared = ctx.service(name)
    wanted = bool(declared and declared.gpu and t.host.gpu)
    if _reserves_gpu(svc) != wanted:
        state = "reserves no GPU although it is a gpu service" if wanted else "reserves a GPU the robot does not have"
        outcome = "run it without the GPU" if wanted else "fail to start it"
        yield ("services", name, "gpu"), (
            f"service {shown(name)} on {ROBOTS} {state}: compose would {outcome}; fix the compose template")


def _reserves_gpu(svc: Mapping[str, Any]) -> bool:
    devices = _dig(svc, "deploy", "resources", "reservations").get("devices")
    return any("gpu" in (d.get("capabilities") or []) or d.get("driver") == "nvidia"
               for d in _as_list(devices) if isinstance(d, dict)) or svc.get("runtime") == "nvidia"


def _dig(data: Any, *keys: str) -> Mapping[str, Any]:
    """data[k1][k2]... as a mapping, or {} when any level is missing or not a mapping (a user template's shape)."""
    for key in keys:
        data = data.get(key) if isinstance(data, dict) else None
    return data if isinstance(data, dict) else {}


def _as_list(value: Any) -> list:
    return value if isinstance(value, list) else [] if value is None else [value]
