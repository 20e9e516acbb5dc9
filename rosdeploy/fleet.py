"""The fleet file (playbooks/*.yml): what runs on every robot and how it is rolled out.

`load_fleet` reads it strictly. An unknown key, a wrong type, or a value that
could break the rendered compose file, the .env or a remote shell command is
reported with file:line, the key path and a fix; every problem in the file is
collected first and raised together as one FleetSpecError, so a user fixes the
file in one pass instead of one error per run.

The schema is data (one table per section, one small converter per value kind)
so the key reference in the README (The fleet file) and the code read the same.
"""
from __future__ import annotations

import dataclasses
import datetime
import difflib
import errno
import functools
import glob
import io
import ipaddress
import math
import os
import posixpath
import stat
import re
import shlex
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

from rosdeploy import ready as readiness, rotation, schema_quick, window as windows, yamlsrc
from rosdeploy.errors import FleetSpecError, InputError, Problem, shown
from rosdeploy.images.refs import DIGEST_RE, parse_rate
from rosdeploy.model import (FleetSpec, HealthCheck, HealthPolicy, ImagePolicy, RobotFile, RollbackPolicy,
                             RolloutPolicy,
                             Service, Topic, frozen_map)
from rosdeploy.yamlsrc import Doc, Encrypted, KeyPath

HEALTH_FROM_IMAGE = "image"

# Names that reach compose project/service names, file names and shell commands.
NAME_RE = re.compile(r"[a-z0-9][a-z0-9_-]{0,62}")
ENV_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
DEVICE_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
TAG_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}")
USER_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*(:[A-Za-z0-9_][A-Za-z0-9_.-]*)?")
TOPIC_RE = readiness.TOPIC_RE     # one rule for a declared topic and a readiness condition's
GROUP_PREFIX_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
ABSOLUTE_PATH_RE = re.compile(r"(/[A-Za-z0-9_.@+-]+)+/?")
# Where rosdeploy mounts things itself (rendered DDS profile, /dev/shm, ROS logs): a bind
# mount of the user's may not land on or under them.
MANAGED_MOUNTS = ("/fastdds.xml", "/cyclonedds.xml", "/dev/shm", "/ros_log")
REMOTE_PATH_RE = re.compile(r"(~|~/[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*|(/[A-Za-z0-9_.-]+)+)/?")
# A deploy root holds releases/<version>-<digest>/<file>, the lock and the history: a quarter of
# Linux's PATH_MAX (4096) leaves room for what goes below it, and no real folder comes near it.
# NAME_MAX (255) bounds each name in it (REMOTE_PATH_RE is ASCII: characters are bytes).
MAX_REMOTE_ROOT = 1024
MAX_PATH = 4096        # Linux's PATH_MAX, in bytes
MAX_PATH_NAME = 255    # NAME_MAX: each name in a path
_DOMAIN = (r"(?:localhost|[A-Za-z0-9](?:[A-Za-z0-9-]*[A-Za-z0-9])?(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]*[A-Za-z0-9])?)*)"
           r"(?::[0-9]{1,5})?")
_COMPONENT = r"[a-z0-9]+(?:(?:[._]|__|-+)[a-z0-9]+)*"
REGISTRY_RE = re.compile(rf"{_DOMAIN}(?:/{_COMPONENT})*")
REPOSITORY_RE = re.compile(rf"{_COMPONENT}(?:/{_COMPONENT})*")
# Docker's reference grammar (distribution/reference NameTotalLengthMax): the whole repository
# name, registry host included, is at most 255 characters; the tag's 128 is in TAG_RE.
MAX_IMAGE_NAME = 255
_DURATION_PART = re.compile(r"([0-9]+(?:\.[0-9]+)?)(ms|h|m|s)")   # ASCII digits only: int("²") fails
_SIZE_RE = re.compile(r"([0-9]+(?:\.[0-9]+)?)([kmg])b?", re.IGNORECASE)
_UNITS = {"ms": 0.001, "s": 1, "m": 60, "h": 3600}
MAX_LIMIT_BYTES = 2**63 - 1           # Docker keeps memory and log sizes as int64
MAX_CPUS = 1024
MIN_CPUS = 0.01                       # Docker refuses a smaller --cpus ("range of CPUs is from 0.01 to ...")
# A size (memory, shm, log file) past 1 TiB is a typo on a robot; far longer ones overflow a float.
MAX_SIZE_BYTES = 1 << 40
MAX_KNOWN_HOSTS = 16 << 20            # bytes: 100,000 robots' keys take ~10 MB; /dev/zero, without end
MAX_DURATION = 366 * 24 * 3600.0      # a year: no wait, deadline or window is longer
_SECRET_ENV_REF = re.compile(r"\$\{?ROSDEPLOY_VAULT_PASSWORD")
_CONTROL = {"\n": "a newline", "\r": "a carriage return", "\0": "a NUL byte"}

# rosdeploy sets these per robot (checklist item 8): a fleet file must not hard-code them.
# ROS_LOG_DIR: the container's /ros_log, the robot's logs/<service> that its logrotate rotates; moved
# elsewhere, the logs fill the container's layer unrotated.
RESERVED_ENV = frozenset({"ROS_DOMAIN_ID", "RMW_IMPLEMENTATION", "CYCLONEDDS_URI",
                          "FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE",
                          "NVIDIA_VISIBLE_DEVICES", "ROS_LOG_DIR"})
# compose keys rosdeploy renders from fleet keys; `compose:` may not override them.
MANAGED_COMPOSE = {"image": "image/tag", "command": "command", "environment": "environment",
                   "env_file": "environment", "devices": "devices", "restart": "restart",
                   "mem_limit": "resources.memory", "cpus": "resources.cpus", "deploy": "resources/gpu",
                   "runtime": "gpu",
                   "healthcheck": "healthcheck", "depends_on": "depends_on", "user": "user",
                   "privileged": "privileged", "profiles": "profiles", "logging": "logging (top level)",
                   "network_mode": "ros.network_mode", "networks": "ros.network_mode", "shm_size": "ros.shm_size",
                   "build": "image", "group_add": "devices (their groups, dialout or video, are added for you)",
                   "volumes": "volumes (bind mounts of robot directories; the DDS config, /dev/shm and logs "
                              "are mounted for you)",
                   "labels": "project/service/version labels (rendered)",
                   # Not rendered, refused: they would bring in what `check` never sees (another
                   # container's mounts, a compose file on the robot) or break the switch between
                   # releases (a fixed container name cannot exist twice).
                   "volumes_from": "volumes (bind mounts of robot directories)",
                   "extends": "the service's own keys (what runs is what the fleet file says)",
                   "container_name": "the service name (containers are named by project and service)"}

Convert = Callable[["Reader", KeyPath, Any], Any]


# ------------------------------------------------------------------ values

def parse_duration(value: Any) -> float:
    """`90`, `90s`, `2m`, `1m30s`, `500ms` -> seconds. ValueError when it is none of those, or
    longer than MAX_DURATION: a wait of 1e23 s (or `.inf`, `.nan`) overflows every timer it reaches."""
    if isinstance(value, bool) or value is None:
        raise ValueError(value)
    if isinstance(value, (int, float)):
        seconds = float(value) if abs(value) <= MAX_DURATION else math.inf
    else:
        text = str(value).strip()
        if re.fullmatch(r"[0-9]+(\.[0-9]+)?", text):
            text += "s"
        parts = _DURATION_PART.findall(text)
        if not parts or "".join(n + u for n, u in parts) != text:
            raise ValueError(value)
        seconds = sum(float(n) * _UNITS[u] for n, u in parts)
    if not 0 <= seconds <= MAX_DURATION:    # NaN fails this too
        raise ValueError(value)
    return seconds


def compose_duration(seconds: float) -> str:
    """Seconds in the form compose's healthcheck fields take: `90s`, `1500ms`."""
    return f"{int(seconds)}s" if seconds == int(seconds) else f"{round(seconds * 1000)}ms"


def size_bytes(text: str | int) -> int:
    """`512m`, `1g`, `256mb` (binary units, as Docker reads them) or a plain byte count -> bytes."""
    if isinstance(text, int) and not isinstance(text, bool):
        return text
    match = _SIZE_RE.fullmatch(str(text).strip())
    if not match:
        if re.fullmatch(r"[0-9]+", str(text).strip()):
            return int(str(text).strip())
        raise ValueError(text)
    number = float(match.group(1)) * 1024 ** ("kmg".index(match.group(2).lower()) + 1)
    if not math.isfinite(number):    # 400 nines overflow to inf, and int(inf) raises OverflowError
        raise ValueError(text)
    return int(number)


def _kind(value: Any) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"true/false ({str(value).lower()})"
    if isinstance(value, (int, float)):
        return f"a number ({value})"
    if isinstance(value, str):
        return f"a string ({shown(value)})"
    if isinstance(value, (datetime.date, datetime.datetime)):    # YAML reads 2024-01-01 as a date
        return f"a date ({value.isoformat()}; quote it for text)"
    if isinstance(value, bytes):
        return "binary data (!!binary)"
    return "a list" if isinstance(value, list) else "a mapping"


# ------------------------------------------------------------------ reader

class Invalid(Exception):
    """A converter's verdict: this value cannot be used (the one way a converter refuses).

    `message` is reported at the value's key path, or at `at` below it; an Invalid without a
    message means the problems inside the value were reported already (a list whose items failed).
    """

    def __init__(self, message: str = "", at: KeyPath = ()) -> None:
        super().__init__(message)
        self.message = message
        self.at = at


class Reader:
    """Walks one fleet Doc and collects problems instead of stopping at the first.

    Converters raise Invalid; `take` records it and leaves the value out of the converted data,
    and remembers its key path (`refused`), so a check across keys can tell a key that is
    missing from one whose value was refused (and already reported).
    """

    def __init__(self, doc: Doc) -> None:
        self.doc = doc
        self.base = Path(doc.path).parent
        self.problems: list[Problem] = []
        self.refused: set[KeyPath] = set()
        self._reported: set[KeyPath] = set()
        self._poisoned: set[KeyPath] = set()   # values holding control characters

    def error(self, kp: KeyPath, message: str) -> None:
        """Record one problem per key path (none under a value already refused for control characters)."""
        if kp in self._reported or any(kp[:n] in self._poisoned for n in range(len(kp) + 1)):
            return
        self._reported.add(kp)
        self.problems.append(self.doc.problem(kp, message))

    def take(self, convert: Convert, kp: KeyPath, value: Any, out: dict, key: Any) -> None:
        """out[key] = the converted value; if the converter refuses it, its problem is recorded instead."""
        try:
            out[key] = convert(self, kp, value)
        except Invalid as exc:
            if exc.message:
                self.error(kp + exc.at, exc.message)
            self.refused.add(kp)

    def refused_in(self, kp: KeyPath) -> bool:
        """Was a value directly inside kp refused?"""
        return any(len(r) == len(kp) + 1 and r[:len(kp)] == kp for r in self.refused)

    def names(self, kp: KeyPath, converted: Any) -> list[str]:
        """The keys of the mapping at kp that were converted or refused, in the file's order: every
        name the file declares there (a bad key name is neither)."""
        raw = self.raw(kp)
        done = converted if isinstance(converted, dict) else {}
        return [k for k in (raw if isinstance(raw, dict) else ()) if k in done or kp + (k,) in self.refused]

    def items(self, kp: KeyPath) -> list[tuple[int, Any]]:
        """(index, value) of the list at kp as written, without the items a converter refused."""
        raw = self.raw(kp)
        return [(i, v) for i, v in enumerate(raw if isinstance(raw, list) else ()) if kp + (i,) not in self.refused]

    def raw(self, kp: KeyPath) -> Any:
        """The value at kp as the file wrote it (None where there is none)."""
        value = self.doc.data
        for key in kp:
            if isinstance(value, dict):
                value = value.get(key)
            elif isinstance(value, list) and isinstance(key, int) and 0 <= key < len(value):
                value = value[key]
            else:
                return None
        return value

    def scan_control_chars(self, value: Any, kp: KeyPath = ()) -> None:
        """Newlines and NULs would split a .env line, a YAML scalar or a shell word: refuse them anywhere."""
        if isinstance(value, dict):
            for key, item in value.items():
                self._check_text(kp + (key,), str(key), "key")
                self.scan_control_chars(item, kp + (key,))
        elif isinstance(value, list):
            for i, item in enumerate(value):
                self.scan_control_chars(item, kp + (i,))
        elif isinstance(value, Encrypted):    # left as ciphertext, it would be written out as such
            self.error(kp, "a `!vault` value is decrypted only in the inventory's vars files: put it in "
                           "group_vars or host_vars, and pass it to the service with `secrets:`")
            self._poisoned.add(kp)
        elif isinstance(value, str):
            self._check_text(kp, value, "value")

    def _check_text(self, kp: KeyPath, text: str, what: str) -> None:
        found = [name for char, name in _CONTROL.items() if char in text]
        if found:
            self.error(kp, f"{what} contains {' and '.join(found)}: it would break the rendered files and "
                           "remote commands; write it on one line (a YAML `|` block is not allowed here)")
            self._poisoned.add(kp)

    def unknown_keys(self, kp: KeyPath, value: dict, allowed: Iterable[str]) -> set[str]:
        """Report keys not in `allowed` with a did-you-mean; returns the keys suggested."""
        allowed = list(allowed)
        suggested: set[str] = set()
        for key in value:
            if key in allowed:
                continue
            close = suggest(str(key), allowed)
            hint = f"did you mean `{close[0]}`?" if close else f"the keys here are: {', '.join(allowed)}"
            self.error(kp + (key,), f"unknown key `{key}`: {hint}")
            suggested.update(close)
        return suggested

    def local_path(self, kp: KeyPath, value: Any, base: Path | None = None) -> Any:
        """A path on this machine: ~ and $VARS expanded, relative to the fleet file's folder."""
        if not isinstance(value, str) or not value.strip():
            raise Invalid(f"must be a path (a string); got {_kind(value)}")
        if "\0" in value:       # no file name holds one: os.stat() would raise ValueError
            raise Invalid("holds a NUL byte, which no path can: remove it")
        if _SECRET_ENV_REF.search(value):
            raise Invalid("a path may not use the vault password variables: they are secrets")
        expanded = os.path.expandvars(value)
        unset = re.search(r"\$\{?([A-Za-z_][A-Za-z0-9_]*)", expanded)
        if unset:
            raise Invalid(f"environment variable ${unset.group(1)} is not set: export it, "
                          "or write the path without it")
        expanded = os.path.expanduser(expanded)   # os.path's: an unknown ~user stays, Path's raises
        if expanded.startswith("~"):
            raise Invalid(f"there is no user {expanded[1:].split('/', 1)[0]!r} to expand "
                          f"{expanded.split('/', 1)[0]} for: write the path without it")
        # Absolute, so later stages (the renderer, remote commands) need not know where the fleet file was.
        return os.path.abspath((base or self.base) / expanded)


# -------------------------------------------------------------- converters

def _section(schema: Mapping[str, Convert], required: tuple[str, ...] = ()) -> Convert:
    """A mapping with a fixed set of keys; returns {key: converted value} for the keys present."""
    def convert(r: Reader, kp: KeyPath, value: Any) -> Any:
        if not isinstance(value, dict):
            raise Invalid(f"must be a mapping with the keys {', '.join(schema)}; got {_kind(value)}")
        suggested = r.unknown_keys(kp, value, schema)
        for key in required:
            if key not in value and key not in suggested:
                r.error(kp + (key,), f"required key missing: add `{key}:` here")
        out: dict[str, Any] = {}
        for key, conv in schema.items():
            if key in value:
                r.take(conv, kp + (key,), value[key], out, key)
        return out
    return convert


def _named(kind: str, what: str, item: Convert) -> Convert:
    """A mapping whose keys the user names (services, environment, vars); `kind`: a key of _PATTERNS."""
    key_re = _PATTERNS[kind][0]

    def convert(r: Reader, kp: KeyPath, value: Any) -> Any:
        if not isinstance(value, dict):
            raise Invalid(f"must be a mapping of {what} names to values; got {_kind(value)}")
        out: dict[str, Any] = {}
        for key, sub in value.items():
            if not isinstance(key, str) or not key_re.fullmatch(key):
                r.error(kp + (key,), f"`{key}` is not a valid {what} name: use {_pattern_hint(kind)}")
            else:
                r.take(item, kp + (key,), sub, out, key)
        return out
    return convert


def _pattern_hint(name: str) -> str:
    pattern, hint = _PATTERNS[name]
    return hint or f"only the characters of the pattern {pattern.pattern}"


# Each kind of name: its pattern and how to say it. Keyed by name, not by pattern: re caches
# compiled patterns, so two kinds written alike (device names, group prefixes) are one object.
_PATTERNS: dict[str, tuple[re.Pattern, str]] = {
    "name": (NAME_RE, "lower-case letters, digits, `_` and `-`, starting with a letter or digit (at most 63)"),
    "env": (ENV_RE, "letters, digits and `_`, not starting with a digit"),
    "device": (DEVICE_RE, "letters, digits, `_`, `.` and `-` (the key of the device in the robot's inventory "
                          "`devices`)"),
    "group prefix": (GROUP_PREFIX_RE, "letters, digits, `_`, `.` and `-`, starting with a letter, digit or `_` "
                                      "(the start of the inventory group names to order the waves by)"),
    "user": (USER_RE, 'a user name, a uid or uid:gid, e.g. "1000:1000"'),
    "topic": (TOPIC_RE, "an absolute name of letters, digits and `_` parts (no `__`), e.g. /joint_states or "
                        "/camera/image_raw"),
    "remote path": (REMOTE_PATH_RE, "an absolute path or one under ~, of letters, digits, `_`, `.`, `-` and `/` "
                                    "only"),
}


def _string(kind: str | None = None, what: str = "") -> Convert:
    """A string; with `kind` (a key of _PATTERNS), one of that kind of name."""
    def convert(r: Reader, kp: KeyPath, value: Any) -> Any:
        if not isinstance(value, str):
            hint = f'; quote it: "{value}"' if isinstance(value, (int, float)) and not isinstance(value, bool) else ""
            raise Invalid(f"must be a string; got {_kind(value)}{hint}")
        if kind is not None and not _PATTERNS[kind][0].fullmatch(value):
            raise Invalid(f"{shown(value)} is not a valid {what}: use {_pattern_hint(kind)}")
        return value
    return convert


MAX_ID = 2**31 - 1     # runc: "uids and gids must be in range 0-2147483647"


def _user(r: Reader, kp: KeyPath, value: Any) -> Any:
    """A name, uid or uid:gid; a numeric id that runc refuses at the container's start is refused here."""
    user = _string("user", "user (name, uid or uid:gid)")(r, kp, value)
    if any(part.isdigit() and (len(part) > 10 or int(part) > MAX_ID) for part in user.split(":")):
        raise Invalid(f"{shown(user)}: a uid or gid is at most {MAX_ID} (runc refuses larger ones at the start)")
    return user


def _text(r: Reader, kp: KeyPath, value: Any) -> Any:
    """Free text for an environment value: scalars are written as compose would read them."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return value       # as it is: an `!unsafe` string stays one (never templated)
    if isinstance(value, (int, float)):
        return str(value)
    raise Invalid(f"must be a string, number or true/false; got {_kind(value)}")


def _boolean(r: Reader, kp: KeyPath, value: Any) -> Any:
    if not isinstance(value, bool):
        raise Invalid(f"must be true or false; got {_kind(value)}")
    return value


# Docker and Go read counts (retries, max-file) as 64-bit numbers; beyond 2**31 a count is a typo.
MAX_COUNT = 2**31 - 1


def _integer(low: int, high: int = MAX_COUNT) -> Convert:
    def convert(r: Reader, kp: KeyPath, value: Any) -> Any:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise Invalid(f"must be a whole number >= {low} and <= {high}; got {_kind(value)}")
        return value
    return convert


def _positive(r: Reader, kp: KeyPath, value: Any) -> Any:
    # not `.inf` (a rate no topic reaches) nor `.nan` (which is not <= 0 either)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < math.inf:
        raise Invalid(f"must be a number above 0; got {_kind(value)}")
    return float(value)


def _positive_duration(r: Reader, kp: KeyPath, value: Any) -> Any:
    return _positive(r, kp, _duration(r, kp, value))


def _known_hosts_file(r: Reader, kp: KeyPath, value: Any) -> Any:
    path = r.local_path(kp, value)
    problem = known_hosts_problem(path)
    if problem:
        raise Invalid(problem)
    return path


MAX_SSH_CONFIG = 1 << 20     # bytes: an OpenSSH config of a whole fleet is a few KB


def _ssh_config_file(r: Reader, kp: KeyPath, value: Any) -> Any:
    """An OpenSSH client config, read and checked as `status` reads it (Includes followed), so
    validate refuses what status would (a fifo, a binary or 1 GB file, a vault, `Port abc`)."""
    path = r.local_path(kp, value)
    try:
        os.stat(path)
    except OSError as exc:
        raise Invalid(f"{path}: {exc.strerror}: give the path of an OpenSSH client config file") from None
    try:
        read_ssh_config(path)
    except BadSSHConfig as exc:
        raise Invalid(str(exc)) from None
    return path


MAX_INCLUDE_DEPTH = 16       # OpenSSH's READCONF_MAX_DEPTH
MAX_SSH_CONFIG_TOTAL = 4 << 20   # bytes of one config with its Includes: a file included twice at each level is 2**16
_SETTING = re.compile(r"(\w+)(?:\s*=\s*|\s+)(.+)")   # paramiko's SSHConfig.SETTINGS_REGEX: the same lines refused
_MATCH_BARE = ("all", "canonical", "final")


class BadSSHConfig(Exception):
    """An ssh config rosdeploy refuses, at file:line when a line is to blame. `unreadable`: the
    file could not be read at all (a robot error at connect time, as before), else an input error."""

    def __init__(self, file: str, line: int | None, message: str, unreadable: bool = False) -> None:
        super().__init__(f"{file}:{line}: {message}" if line else f"{file} {message}")
        self.file, self.line, self.message, self.unreadable = file, line, message, unreadable


class SSHConfigText:
    """A config with its Includes spliced in: the lines paramiko parses, where each came from, and
    every file read (their mtimes key the caches that must see an edited included file)."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.origins: list[tuple[str, int]] = []
        self.files: list[str] = []
        self.size = 0

    def add(self, line: str, origin: tuple[str, int]) -> None:
        self.lines.append(line)
        self.origins.append(origin)


def read_ssh_config(path: str) -> SSHConfigText:
    """`path` and what it Includes, each line checked for the values fabric and paramiko would turn
    into a crash (ValueError, KeyError) at connect time. Reading runs nothing (`Match exec` runs only
    at lookup). Relative Includes resolve against ~/.ssh, or /etc/ssh for the system config, as in OpenSSH."""
    base = "/etc/ssh" if os.path.abspath(path) == "/etc/ssh/ssh_config" else os.path.expanduser("~/.ssh")
    out = SSHConfigText()
    _read_config_into(out, path, base, (os.path.realpath(path),))
    return out


def _read_config_into(out: SSHConfigText, path: str, base: str, stack: tuple[str, ...]) -> bool:
    """Append `path`'s lines to `out`; True when they (or their Includes) hold a Host or Match line."""
    text = _config_text(path)
    out.files.append(path)
    out.size += len(text)
    if out.size > MAX_SSH_CONFIG_TOTAL:
        raise BadSSHConfig(path, None, f"and its Includes are larger than {MAX_SSH_CONFIG_TOTAL >> 20} MB together")
    headers, conditional = False, False
    for number, raw in enumerate(io.StringIO(text), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        found = _SETTING.match(line)
        if not found:
            raise BadSSHConfig(path, number, "not an OpenSSH client config line (the line is not shown): fix it, or "
                                             "`ssh.config` in the fleet file")
        key = found.group(1).lower()
        value = found.group(2) if key in ("host", "match") else _unquoted(found.group(2))
        if key == "include":
            inner = _include(out, value, base, stack, (path, number))
            if inner and conditional:
                raise BadSSHConfig(path, number, "Include inside a Host or Match block, of a file with Host or Match "
                                                 "lines, is not supported: move the Include above the first Host "
                                                 "or Match line")
            if inner:      # OpenSSH goes back to the including block: here the top level
                out.add("Host *\n", (path, number))
            continue
        why = _SETTING_CHECKS[key](value) if key in _SETTING_CHECKS else None
        if why:
            raise BadSSHConfig(path, number, f"{found.group(1)}: {why}")
        if key in ("host", "match"):
            headers = True
            conditional = value.strip() not in ("*", "all")
        out.add(raw, (path, number))
    return headers


def _include(out: SSHConfigText, value: str, base: str, stack: tuple[str, ...], at: tuple[str, int]) -> bool:
    """Follow one Include line: its globs, in order, each match read as a config of its own."""
    try:
        patterns = shlex.split(value)
    except ValueError:
        raise BadSSHConfig(*at, "Include: unbalanced quotes") from None
    headers = False
    for pattern in patterns:
        pattern = os.path.join(base, os.path.expanduser(pattern))   # an absolute one stays as it is
        for each in sorted(glob.glob(pattern)):    # OpenSSH: no match is no file, silently
            real = os.path.realpath(each)
            if real in stack:
                raise BadSSHConfig(*at, f"Include loop: {each} includes itself again")
            if len(stack) >= MAX_INCLUDE_DEPTH:
                raise BadSSHConfig(*at, f"Includes nested deeper than {MAX_INCLUDE_DEPTH} (OpenSSH's limit)")
            headers |= _read_config_into(out, each, base, (*stack, real))
    return headers


def _config_text(path: str) -> str:
    """One config file's text: a regular UTF-8 file of at most MAX_SSH_CONFIG bytes, never a vault
    password file (its text unlocks every vault: never parsed, never quoted)."""
    from rosdeploy.vault import is_password_file    # here: validate of a fleet without vault never imports it
    if is_password_file(path):
        raise BadSSHConfig(path, None, "is a vault password file, not an ssh config: fix `ssh.config` in the fleet "
                                       "file")
    problem = _file_problem(path, MAX_SSH_CONFIG, "an OpenSSH client config file", "OpenSSH config file")
    if problem:
        raise BadSSHConfig(path, None, problem.removeprefix(path).lstrip(), unreadable=True)
    try:
        return yamlsrc.read_bytes(path, MAX_SSH_CONFIG, "an OpenSSH client config").decode("utf-8")
    except UnicodeDecodeError:
        raise BadSSHConfig(path, None, "is not UTF-8 text: give the path of an OpenSSH client config file",
                           unreadable=True) from None
    except InputError as exc:
        raise BadSSHConfig(path, None, exc.problems[0].message, unreadable=True) from None


def _unquoted(value: str) -> str:
    """A value as paramiko stores it: one pair of surrounding double quotes removed."""
    return value[1:-1] if len(value) > 1 and value.startswith('"') and value.endswith('"') else value


def _port_problem(value: str) -> str | None:
    # fabric calls int() on it (ValueError: an internal error), and a socket takes 99999 as 34463
    if re.fullmatch(r"[0-9]{1,5}", value.strip()) and 1 <= int(value) <= 65535:
        return None
    return f"{shown(value, 20)} is not a port: give a number from 1 to 65535"


def _count_problem(value: str) -> str | None:
    return None if re.fullmatch(r"[0-9]{1,6}", value.strip()) else f"{shown(value, 20)} is not a whole number"


def _jump_problem(value: str) -> str | None:
    try:
        hops = proxy_jump_hops(value)
    except ValueError as exc:
        return str(exc)
    return next((f"jump host {why}" for why in (host_name_problem(host) for _, host, _ in hops) if why), None)


def host_name_problem(host: str) -> str | None:
    """Why a literal HostName or jump host can reach no resolver, or None. The idna codec refuses an
    empty label, one over 63 characters, or `\x85` with a UnicodeError (not an OSError): it passed
    validate and stopped `plan` with an internal error. A `%h`-style token is known at connect time only."""
    host = host.strip()
    if "%" in host and not is_ip_address(host):
        return None
    if not host.isprintable():
        bad = ", ".join(sorted({repr(c) for c in host if not c.isprintable()}))
        return f"{shown(host, 40)} holds {bad}: give a host name or IP address"
    if is_ip_address(host):
        return None
    try:
        host.encode("idna")
    except UnicodeError:
        return (f"{shown(host, 40)} is not a valid host name (a dot-separated label is empty or longer than 63 "
                "characters): give a host name or IP address")
    return None


def is_ip_address(text: str) -> bool:
    """An IPv4 or IPv6 address (an IPv6 `%zone` included), as Python's ipaddress reads one."""
    try:
        ipaddress.ip_address(text)
        return True
    except ValueError:
        return False


def proxy_jump_hops(value: str) -> list[tuple[str | None, str, int | None]]:
    """ProxyJump's hops as (user, host, port), first hop first; `none` is no hop, as in OpenSSH."""
    if value.strip().lower() == "none":
        return []
    hops = []
    for hop in value.split(","):
        spec = hop.strip().removeprefix("ssh://")
        user, _, hostport = spec.rpartition("@")
        host, port = hostport, None
        bracketed = re.fullmatch(r"\[([^\]]+)\](?::(.*))?", hostport)
        if bracketed:
            host, port = bracketed.group(1), bracketed.group(2)
        elif hostport.count(":") == 1:
            host, port = hostport.split(":")
        if not host or (port is not None and _port_problem(port)):
            raise ValueError(f"{shown(hop.strip(), 40)} is not a jump host: write [user@]host[:port], "
                             "the port from 1 to 65535")
        hops.append((user or None, host, int(port) if port is not None else None))
    return hops


def _match_problem(value: str) -> str | None:
    """paramiko's parse-time checks of a Match line (SSHConfig._get_matches)."""
    try:
        tokens = shlex.split(value)
    except ValueError:
        return "unbalanced quotes"
    kinds = []
    while tokens:
        kind = tokens.pop(0).lstrip("!")
        kinds.append(kind)
        if kind not in _MATCH_BARE and not tokens:
            return f"{shown(kind, 20)} needs a value"
        if kind not in _MATCH_BARE:
            tokens.pop(0)
    if "all" in kinds and set(kinds) - {"all", "canonical"}:
        return "`all` goes alone (or after `canonical`)"
    if "all" in kinds and "canonical" in kinds and kinds.index("canonical") > kinds.index("all"):
        return "`canonical` goes before `all`"
    return None


_SETTING_CHECKS: dict[str, Callable[[str], str | None]] = {
    "port": _port_problem, "canonicalizemaxdots": _count_problem, "proxyjump": _jump_problem,
    "match": _match_problem, "hostname": host_name_problem,
}


def known_hosts_problem(path: str) -> str | None:
    """Why `path` cannot be a known_hosts file (a fifo hangs the read, /dev/zero fills memory), or
    None; a missing one is each robot's error, as OpenSSH makes it. For ssh.known_hosts and the
    inventory's rosdeploy_known_hosts."""
    return _file_problem(path, MAX_KNOWN_HOSTS, "a known_hosts file", "known_hosts file")


def _file_problem(path: str, limit: int, wanted: str, kind: str) -> str | None:
    """Why `path` cannot be read as `wanted` (not a regular file, or over `limit` bytes), or None
    (a missing file included: each caller says what that means)."""
    try:
        info = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:      # a symlink loop, no permission: "not in known_hosts" would send the user astray
        return f"{path} cannot be read: {exc.strerror}: give the path of {wanted}"
    if not stat.S_ISREG(info.st_mode):
        return f"{path} is not a regular file (a fifo, a device or a directory): give the path of {wanted}"
    if info.st_size > limit:
        return f"{path} is larger than {limit >> 20} MB: that is no {kind}"
    return None


def _duration(r: Reader, kp: KeyPath, value: Any) -> Any:
    try:
        return parse_duration(value)
    except ValueError:
        raise Invalid(f"must be a duration like 90, 90s, 2m or 1m30s, at most 8784h (a year); "
                      f"got {_kind(value)}") from None


def _size(r: Reader, kp: KeyPath, value: Any) -> Any:
    if not isinstance(value, str) or not _SIZE_RE.fullmatch(value.strip()):
        raise Invalid(f"must be a size with a unit like 512m or 1g; got {_kind(value)}")
    try:
        too_big = size_bytes(value) > MAX_SIZE_BYTES
    except ValueError:
        too_big = True
    if too_big:
        raise Invalid(f"{shown(value, 20)} is more than {MAX_SIZE_BYTES >> 30}g: no robot has that much memory "
                      "or log space; give a size like 512m or 1g")
    return value.strip().lower()


def _enum(*choices: str) -> Convert:
    def convert(r: Reader, kp: KeyPath, value: Any) -> Any:
        if value not in choices:
            raise Invalid(f"must be one of {', '.join(choices)}; got {_kind(value)}")
        return value
    return convert


def _listof(item: Convert, what: str) -> Convert:
    def convert(r: Reader, kp: KeyPath, value: Any) -> Any:
        if not isinstance(value, list):
            raise Invalid(f"must be a list of {what}; got {_kind(value)}")
        out: dict[int, Any] = {}
        for i, v in enumerate(value):
            r.take(item, kp + (i,), v, out, i)
        for i, v in enumerate(value):
            if isinstance(v, (str, int)) and value.index(v) < i:
                r.error(kp + (i,), f"{shown(v)} is listed twice; keep one")
        if len(out) < len(value):
            raise Invalid()   # its items' problems are reported; Reader.items reads the others
        return tuple(out[i] for i in range(len(value)))
    return convert


# ------------------------------------------------------ values with meaning

def _tag(r: Reader, kp: KeyPath, value: Any) -> Any:
    value = _string()(r, kp, value)
    if not value.strip() or value.strip().lower() == "latest":
        raise Invalid(f"{shown(value)} is not a release version: every deploy needs an explicit tag that "
                      'can be rolled back to, e.g. "1.4.2" or "1.4.2-3f9a2c1" (version and commit)')
    if not TAG_RE.fullmatch(value):
        raise Invalid(f"{shown(value)} is not a valid image tag: use letters, digits, `_`, `.` and `-` "
                      "(at most 128, not starting with `.` or `-`)")
    return value


def _registry(r: Reader, kp: KeyPath, value: Any) -> Any:
    value = _string()(r, kp, value)
    if not REGISTRY_RE.fullmatch(value):
        raise Invalid(f"{shown(value)} is not a registry: write host[:port][/path], e.g. registry.local:5000, "
                      "without a scheme (no https://)")
    _check_port(value)
    if not _has_registry_host(value + "/image"):
        host = value.partition("/")[0]
        raise Invalid(f"{shown(host)} has no `.` or port and is not localhost, so Docker reads it as a Docker "
                      f"Hub account, not a registry: write the registry's full name or its port, e.g. "
                      f"{host}.local or {host}:5000")
    return value


def _check_port(address: str) -> None:
    """The port of host[:port][/path], if it has one, is a TCP port."""
    port = re.match(r"[^/]*:([0-9]+)", address)
    if port and not 0 < int(port[1]) < 65536:
        raise Invalid(f"{shown(address)}: port {port[1]} is not a TCP port (1-65535)")


def _image(r: Reader, kp: KeyPath, value: Any) -> Any:
    """A repository without tag; its registry host is checked against `registry` later."""
    value = _string()(r, kp, value)
    if "@" in value:
        value, _, digest = value.partition("@")
        if not DIGEST_RE.fullmatch(digest):
            raise Invalid(f"{shown(digest)} is not an image digest: write repo@sha256:<64 hex digits>, or "
                          "give the repository only and pin the version with `tag:`")
        return f"{_image(r, kp, value)}@{digest}"
    if len(value) > MAX_IMAGE_NAME:
        raise Invalid(_long_image_name(value))
    last = value.rsplit("/", 1)[-1]
    if ":" in last:
        repo, tag = value.rsplit(":", 1)
        raise Invalid(f"`image:` must not carry a tag (`:{tag}`): the release `version` is every image's "
                      f"tag; write `image: {repo}` and, to pin this service, `tag: \"{tag}\"`")
    host, _, rest = value.partition("/")
    if _has_registry_host(value) and REGISTRY_RE.fullmatch(host) and REPOSITORY_RE.fullmatch(rest):
        return value
    if not REPOSITORY_RE.fullmatch(value):
        raise Invalid(f"{shown(value)} is not a valid image repository: use lower-case path components "
                      "(letters, digits, `.`, `_`, `-`) separated by `/`, e.g. acme/amr-driver")
    return value


def _rate(r: Reader, kp: KeyPath, value: Any) -> Any:
    try:
        return parse_rate(value)
    except ValueError as exc:
        why = "it is bits per second" if "bits" in str(exc) else "it is not a rate"
        raise Invalid(f"{shown(value)}: {why}: write bytes per second from 1kB/s up, e.g. 2MB/s or "
                      "500kB/s") from None


def _controller_registry(r: Reader, kp: KeyPath, value: Any) -> Any:
    value = _string()(r, kp, value)
    scheme, sep, address = value.rpartition("://")
    # a path is the registry's, as `registry: host/acme` has one: the repository comes from the image
    if (sep and scheme not in ("http", "https")) or not REGISTRY_RE.fullmatch(address):
        raise Invalid(f"{shown(value)} is not a registry address: write host[:port], optionally after "
                      "http:// or https://, e.g. http://127.0.0.1:5000")
    _check_port(address)
    return value


def _long_image_name(name: str) -> str:
    return (f"the image name {name[:40]!r}... is {len(name)} characters long: Docker refuses a repository "
            f"name (registry host and path together) over {MAX_IMAGE_NAME}; shorten it")


def _has_registry_host(image: str) -> bool:
    first, sep, _ = image.partition("/")
    return bool(sep) and ("." in first or ":" in first or first == "localhost")


def _command(r: Reader, kp: KeyPath, value: Any) -> Any:
    """A list of words (exec form). A string is split like a shell would, but never run by one."""
    if isinstance(value, str):
        try:
            value = shlex.split(value)
        except ValueError as exc:
            raise Invalid(f"cannot split the command into words ({exc}): write it as a list, "
                          "e.g. [ros2, launch, amr_driver, driver.launch.py]") from None
    if not isinstance(value, list) or not value:
        raise Invalid(f"must be a non-empty list of words; got {_kind(value)}")
    words: dict[int, str] = {}
    for i, word in enumerate(value):
        r.take(_text, kp + (i,), word, words, i)
    if len(words) < len(value):
        raise Invalid()
    if not words[0].strip():    # no program: the container (or the check) fails to start it
        raise Invalid("is empty: the first word is the program to run, e.g. ros2", (0,))
    return tuple(words[i] for i in range(len(value)))


def _healthcheck(r: Reader, kp: KeyPath, value: Any) -> Any:
    if value == HEALTH_FROM_IMAGE:
        return HEALTH_FROM_IMAGE
    if not isinstance(value, dict):
        raise Invalid(f"must be a mapping (test, interval, timeout, retries, start_period) or `image` "
                      f"to trust the image's own HEALTHCHECK; got {_kind(value)}")
    d = _section(_HEALTHCHECK, required=("test",))(r, kp, value)
    if r.refused_in(kp) or "test" not in d:
        raise Invalid()
    times = {k: compose_duration(d[k]) for k in ("interval", "timeout", "start_period") if k in d}
    return HealthCheck(test=d["test"], retries=d.get("retries", 3), **times)


def _health_test(r: Reader, kp: KeyPath, value: Any) -> Any:
    """[CMD, ...] / [CMD-SHELL, "..."] as compose takes it; a plain string is CMD-SHELL."""
    if isinstance(value, str):
        if not value.strip():
            raise Invalid("is empty: give the command to run")
        return ("CMD-SHELL", value)
    words = _command(r, kp, value)
    if words[0] not in ("CMD", "CMD-SHELL") or len(words) < 2:
        raise Invalid('must start with CMD or CMD-SHELL and then the command, e.g. '
                      '[CMD-SHELL, "ros2 topic list | grep -q /joint_states"]')
    if not words[1].strip():    # CMD: no program to run, never healthy; CMD-SHELL: `sh -c ''`, always healthy
        raise Invalid(f"is empty: give the command to run after {words[0]}", (1,))
    if words[0] == "CMD-SHELL" and len(words) > 2:    # Docker runs `sh -c "a" "b"`: "b" is only $0
        raise Invalid('CMD-SHELL takes one string, the shell command (the words after it would be dropped): '
                      'write [CMD-SHELL, "a b"], or [CMD, a, b] to run it without a shell', (2,))
    return words


def _topic(r: Reader, kp: KeyPath, value: Any) -> Any:
    if isinstance(value, str):
        value = {"name": value}
    d = _section(_TOPIC, required=("name",))(r, kp, value)
    if r.refused_in(kp) or "name" not in d:
        raise Invalid()
    return Topic(name=d["name"], min_rate=d.get("min_rate"))


def _topics(r: Reader, kp: KeyPath, value: Any) -> Any:
    """A service's declared topics, each once (a second entry would be probed and judged twice)."""
    topics = _listof(_topic, "topics")(r, kp, value)
    seen: dict[str, int] = {}
    for i, topic in enumerate(topics):
        if topic.name in seen:
            r.error(kp + (i,), f"{topic.name} is already declared at topics[{seen[topic.name]}]: keep one (with "
                               "the min_rate it needs)")
        seen.setdefault(topic.name, i)
    if len(seen) < len(topics):
        raise Invalid()
    return topics


WAVE_HINT = 'a robot count (1, 5) or a percentage of the targets ("10%")'


def wave_target(value: Any, least: int = 1) -> int | str:
    """A robot count of at least `least` (1, 5) or a share of the targets ("10%"); ValueError
    otherwise. Shared by the fleet file's rollout keys and apply's --waves and --max-fail."""
    if isinstance(value, int) and not isinstance(value, bool) and least <= value <= MAX_COUNT:
        return value
    if isinstance(value, str) and re.fullmatch(r"[0-9]{1,3}%", value) and 0 < int(value[:-1]) <= 100:
        return value
    raise ValueError(value)


def _wave(r: Reader, kp: KeyPath, value: Any) -> Any:
    try:
        return wave_target(value)
    except ValueError:
        raise Invalid(f"must be {WAVE_HINT}, a count at most {MAX_COUNT}; got {_kind(value)}") from None


def _max_fail(r: Reader, kp: KeyPath, value: Any) -> Any:
    try:
        return wave_target(value, least=0)
    except ValueError:
        raise Invalid(f"must be 0 or {WAVE_HINT}, a count at most {MAX_COUNT}; got {_kind(value)}") from None


def _restart(r: Reader, kp: KeyPath, value: Any) -> Any:
    if value is False or value == "no":   # YAML reads a bare `no` as false
        raise Invalid("`no` would leave the service down after a crash or reboot: use unless-stopped "
                      "(services) or always (critical drivers and watchdogs)")
    return _enum("always", "unless-stopped", "on-failure")(r, kp, value)


def _order_by(r: Reader, kp: KeyPath, value: Any) -> Any:
    return None if value is None else _string("group prefix", "group prefix")(r, kp, value)


def _mount(r: Reader, kp: KeyPath, value: Any) -> Any:
    """A bind mount "/robot/path:/container/path[:ro|rw]", normalized to always carry its mode."""
    if not isinstance(value, str):
        raise Invalid(f'must be a string like "/opt/maps:/maps:ro"; got {_kind(value)}')
    parts = value.split(":")
    mode = parts.pop() if len(parts) == 3 and parts[2] in ("ro", "rw") else "rw"
    if len(parts) != 2 or not all(ABSOLUTE_PATH_RE.fullmatch(p) and ".." not in p.split("/") for p in parts):
        raise Invalid(f"{shown(value)} is not a bind mount: use /path/on/robot:/path/in/container, optionally "
                      f"followed by :ro or :rw; both paths absolute, letters, digits and ._@+- only")
    source, target = (normal_path(p) for p in parts)   # `/dev/./shm` is /dev/shm, to Docker and to checks
    # the robot creates a missing source, and runc the target: ENAMETOOLONG, after the images were pulled
    for side, path, example in (("robot", source, "/opt/maps"), ("container", target, "/maps")):
        too_long = path_too_long(path, example)
        if too_long:
            raise Invalid(f"the {side} path is {too_long}")
    taken = managed_mount(target)
    if taken:
        raise Invalid(f"{target} is where rosdeploy mounts {taken} itself: choose another container path")
    problem = proc_mount_problem(target, source)
    if problem:
        raise Invalid(problem)
    return f"{source}:{target}:{mode}"


# runc mounts procfs at /proc and refuses any other mount on or below it but these (lxcfs's
# files among them); libcontainer/rootfs_linux.go, checkProcMount.
PROC_MOUNTS_ALLOWED = frozenset({"/proc/cpuinfo", "/proc/diskstats", "/proc/meminfo", "/proc/stat", "/proc/swaps",
                                 "/proc/uptime", "/proc/loadavg", "/proc/slabinfo", "/proc/net/dev",
                                 "/proc/sys/kernel/ns_last_pid", "/proc/sys/crypto/fips_enabled"})


def proc_mount_problem(target: str, source: str | None = None) -> str | None:
    """Why a mount at this container path would stop the container from being created (or hide
    the kernel's sysfs from it), or None. `source`: a bind mount's path on the robot (None: a file)."""
    if (target == "/proc" or target.startswith("/proc/")) and target not in PROC_MOUNTS_ALLOWED:
        return (f"{target} is in /proc, where the container runtime (runc) refuses a mount: the container "
                "would not be created; mount it elsewhere (a kernel setting goes in `compose: {sysctls: ...}`)")
    if not (target == "/sys" or target.startswith("/sys/")) or source == target:
        return None     # the robot's own sysfs path at its place (/sys/class/gpio): the container's sysfs has it
    same = f", or mount the robot's own {target} there ({target}:{target})" if source is not None else ""
    if target == "/sys":
        return f"a mount at /sys would hide the container's sysfs (the kernel's devices): mount it elsewhere{same}"
    return (f"{target} is in /sys, the container's read-only sysfs, where the container runtime (runc) cannot "
            f"create a mount point: the container would not be created; mount it elsewhere{same}")


def normal_path(path: str) -> str:
    """An absolute path without `.`, `//` or a trailing `/` (`/.` and `//` are `/`)."""
    return "/" + posixpath.normpath("/" + path).lstrip("/")


def managed_mount(target: str) -> str | None:
    """The mount of rosdeploy's own that a container path lands on or under (MANAGED_MOUNTS), or None."""
    target = normal_path(target)
    return next((m for m in MANAGED_MOUNTS if target == m or target.startswith(m + "/")), None)


def _volumes(r: Reader, kp: KeyPath, value: Any) -> Any:
    """Bind mounts, no two at one container path (compose refuses the file: "duplicate mount point")."""
    mounts = _listof(_mount, "bind mounts")(r, kp, value)
    seen: dict[str, int] = {}
    for i, mount in enumerate(mounts):
        target = _mount_target(mount)
        if target in seen:
            r.error(kp + (i,), f"{target} is already the container path of volumes[{seen[target]}]: compose "
                               "refuses two mounts at one path; mount one of them elsewhere")
        seen.setdefault(target, i)
    if len(seen) < len(mounts):
        raise Invalid()
    return mounts


def _mount_target(mount: str) -> str:
    """The container path of a bind mount "/robot:/container[:mode]" as _mount keeps it (normalized)."""
    return normal_path(mount.split(":")[1])


def _compose_extra(r: Reader, kp: KeyPath, value: Any) -> Any:
    """Compose keys passed through verbatim (cap_add, ulimits, ...), except those rosdeploy renders."""
    if not isinstance(value, dict):
        raise Invalid(f"must be a mapping of compose service keys, e.g. {{cap_add: [SYS_NICE]}}; got {_kind(value)}")
    for key in value:
        if key in MANAGED_COMPOSE:
            r.error(kp + (key,), _NOT_PASSED.get(key) or f"`{key}` is rendered by rosdeploy: set it with the fleet "
                                                          f"key `{MANAGED_COMPOSE[key]}` instead")
    return value


# MANAGED_COMPOSE keys with no fleet key to name: why each is refused, and what to do
_NOT_PASSED = {
    "volumes_from": "`volumes_from` is refused: it mounts another container's folders, which `check` never sees; "
                    "mount the robot's folders with the fleet key `volumes`",
    "extends": "`extends` is refused: it brings in a service from a compose file `check` never sees; write the "
               "service's keys in the fleet file",
    "container_name": "`container_name` is refused: a fixed name cannot exist twice while releases switch "
                      "(containers are named by project and service); remove it",
    "labels": "`labels` is rendered by rosdeploy (the project, service and version labels it reads back on the "
              "robot); remove it",
}


# ------------------------------------------- issue 18: refusals (new converters)

DOCKER_MIN_MEMORY = 6 * 1024 * 1024    # dockerd refuses a smaller memory limit
COMPOSE_SCHEMA = Path(__file__).parent / "schemas" / "compose_spec.json"   # see schemas/README.md


def _memory(r: Reader, kp: KeyPath, value: Any) -> Any:
    """A memory limit: a size Docker accepts (`0m` would be refused on the robot, mid-deploy)."""
    value = _size(r, kp, value)
    if size_bytes(value) < DOCKER_MIN_MEMORY:
        raise Invalid(f"{shown(value)} is below Docker's minimum memory limit of 6m: give the service "
                      "what it needs, e.g. 256m")
    return value   # the upper bound is _size's


def _cpus(r: Reader, kp: KeyPath, value: Any) -> Any:
    """A CPU limit: a finite number above 0 (`.inf` would be written as `inf` for compose)."""
    value = _positive(r, kp, value)
    if not math.isfinite(value) or not MIN_CPUS <= value <= MAX_CPUS:
        raise Invalid(f"must be a number of CPUs from {MIN_CPUS} (Docker's least) up to {MAX_CPUS}, "
                      f"e.g. 1.5; got {value}")
    return value


def _log_size(r: Reader, kp: KeyPath, value: Any) -> Any:
    """json-file's max-size: above 0 (`0m` makes dockerd refuse to create the container)."""
    value = _size(r, kp, value)
    if not 0 < size_bytes(value) <= MAX_LIMIT_BYTES:
        raise Invalid(f"{shown(value)}: a log file's size must be above 0 and a 64-bit byte count, e.g. 10m")
    return value


def _waves(r: Reader, kp: KeyPath, value: Any) -> Any:
    """Cumulative wave targets: at least one, never shrinking (counts and percents each)."""
    waves = _listof(_wave, "waves")(r, kp, value)
    problem = wave_order(tuple(dict.fromkeys(waves)))    # a wave listed twice: _listof said so at its line
    if problem:
        raise Invalid(problem)
    return waves


def wave_order(waves: Sequence[int | str]) -> str | None:
    """Why these wave targets are no rollout (none, or one shrinking), or None; for --waves too."""
    if not waves:
        return 'name at least one wave, e.g. [1, "100%"]'
    twice = next((w for i, w in enumerate(waves) if w in waves[:i]), None)
    if twice is not None:
        return f"{shown(twice)} is listed twice; keep one"
    for kind in (int, str):
        sizes = [int(w) if isinstance(w, int) else int(w[:-1]) for w in waves if isinstance(w, kind)]
        if sizes != sorted(sizes):
            return f"waves are cumulative targets and never shrink; got {', '.join(map(str, waves))}"
    return None


def _rotate_every(r: Reader, kp: KeyPath, value: Any) -> Any:
    """logging.rotate_every: a period cron keeps evenly (rotation.py), or off (None)."""
    if value is False or value == "off":     # YAML 1.1 reads a bare `off` as false
        return None
    seconds = _duration(r, kp, value)
    if rotation.cron_schedule(seconds) is None:
        raise Invalid(f"{shown(value)} is not a period cron can keep (it runs at most once a minute, on the "
                      f"clock): use one of {rotation.PERIODS}, or off")
    return seconds


def _deploy_root(r: Reader, kp: KeyPath, value: Any) -> Any:
    """deploy_root: the remote-path pattern (no shell metacharacters), and no `..` anywhere."""
    value = _string("remote path", "path on the robot (absolute or under ~)")(r, kp, value)
    if ".." in value.split("/"):
        raise Invalid(f"{shown(value)} contains `..`: releases would land outside the folder it names; "
                      "write the folder itself, e.g. ~/rosdeploy or /opt/rosdeploy")
    problem = deploy_root_problem(value)
    if problem:
        raise Invalid(problem)
    return value


KERNEL_FOLDERS = ("/proc", "/sys", "/dev")


def deploy_root_problem(path: str) -> str | None:
    """Why a deploy root that passed the remote-path pattern is no folder for releases, or None: the
    robot's root, a folder of the kernel's, or a path too long for Linux. Shared by deploy_root and
    the per-robot rosdeploy_deploy_root."""
    folder = normal_path(path) if path.startswith("/") else ""
    if folder == "/":     # `/.` and `/./` are the root as well
        return (f"{shown(path)} is the robot's root folder: releases need a folder of their own, "
                "e.g. ~/rosdeploy or /opt/rosdeploy")
    kernel = next((k for k in KERNEL_FOLDERS if folder == k or folder.startswith(k + "/")), None)
    if kernel:
        # procfs and sysfs take no new folder, and /dev is devtmpfs (its /dev/shm is emptied at boot):
        # every apply failed at its first mkdir, after the images were pulled
        return (f"{shown(path)} is in {kernel}, the kernel's own file system: the robot cannot keep releases "
                "there; use a folder of its own, e.g. ~/rosdeploy or /opt/rosdeploy")
    return remote_root_too_long(path)


def remote_root_too_long(path: str) -> str | None:
    """Why a deploy root (deploy_root, rosdeploy_deploy_root) is too long for the robot, or None.

    Unbounded, it validated and then failed on the robot at the first mkdir (ENAMETOOLONG), after
    the images were pulled."""
    longest = max(len(name) for name in path.split("/"))
    if len(path) <= MAX_REMOTE_ROOT and longest <= MAX_PATH_NAME:
        return None
    what = (f"a path of {len(path)} characters" if len(path) > MAX_REMOTE_ROOT
            else f"a path with a folder name of {longest} characters")
    return (f"{what}: a deploy root may have at most {MAX_REMOTE_ROOT} characters (releases "
            f"and their files go below it), and {MAX_PATH_NAME} in each name (Linux's limit); use a short "
            "folder, e.g. ~/rosdeploy or /opt/rosdeploy")


def home_problem(value: Any) -> str | None:
    """Why `value` cannot be rosdeploy_home (the SSH user's home, which makes a `~` deploy root
    absolute in the logrotate config), or None. logrotate runs as root: it would read `~` as
    /root, and a relative path from wherever cron starts it."""
    if (not isinstance(value, str) or not value.startswith("/") or not REMOTE_PATH_RE.fullmatch(value)
            or ".." in value.split("/")):
        return ("must be the absolute path of the SSH user's home on the robot, without `~`, `..` or shell "
                f"metacharacters, e.g. /home/ubuntu (logrotate runs as root); got {_kind(value)}")
    return remote_root_too_long(value)


def _fleet_var(r: Reader, kp: KeyPath, value: Any) -> Any:
    """A template variable of `vars:`, as written; the ones rosdeploy itself reads are checked here
    (the DDS and logrotate tunables per robot, in render.py: the inventory may replace them)."""
    problem = home_problem(value) if kp[-1] == "rosdeploy_home" else _inventory_only(str(kp[-1]))
    if problem:
        raise Invalid(problem)
    return value


FLEET_READ_VARS = ("rosdeploy_home",)     # the one rosdeploy_ name render.py takes from `vars:` too
# Per-robot names that have a fleet key of their own, which is where a fleet-wide value goes
_FLEET_KEY_FOR = {"rosdeploy_deploy_root": "deploy_root", "ready": "ready", "rosdeploy_ready": "ready",
                  "window": "window", "rosdeploy_window": "window"}


def _inventory_only(name: str) -> str | None:
    """Why `name` is no fleet `vars:` entry, or None: rosdeploy reads its own per-robot vars and Ansible's
    from the inventory only (inventory/hostvars.py), so here the value would be ignored without a word."""
    from rosdeploy.inventory.hostvars import OWN_VARS, PREFIX, PREFIXED_VARS  # it imports this module
    taken = sorted({*PREFIXED_VARS, *FLEET_READ_VARS})
    if name.startswith(PREFIX) and name not in taken:
        hint = suggest(name, taken)
        return (f"unknown rosdeploy variable {shown(name)}: "
                + (f"did you mean `{hint[0]}`?" if hint else f"known: {', '.join(taken)}")
                + " (the rosdeploy_ prefix is rosdeploy's own)")
    variant = _case_variant(name, taken)
    if variant:
        return variant
    if name not in PREFIXED_VARS and name not in OWN_VARS and not name.startswith("ansible_"):
        return None
    where = "the inventory (group_vars/all.yml for every robot, or the robot's host vars)"
    if name in _FLEET_KEY_FOR:
        where = f"the fleet file's top-level key `{_FLEET_KEY_FOR[name]}:` (every robot), or " + where
    whose = "rosdeploy's per-robot variable, which it takes"
    if name.startswith("ansible_"):    # Ansible's own names are lower case: `ansible_Foo` is only in its namespace
        whose = ("Ansible's per-robot variable, which rosdeploy takes" if name == name.lower()
                 else "in Ansible's `ansible_` namespace, whose variables rosdeploy takes")
    return f"{name} is {whose} from the inventory only, so here it would be ignored: set it in {where}"


def _case_variant(name: str, taken: Sequence[str]) -> str | None:
    """Why `name`, which differs from a rosdeploy_ or Ansible variable in case only (`ROSDEPLOY_GPU`,
    `ansible_Host`), is neither, or None. Variable names are case-sensitive, in Ansible as here: it
    would be a template variable of its own, ignored by rosdeploy without a word."""
    from rosdeploy.inventory.hostvars import CONNECTION, PREFIX
    from rosdeploy.inventory.known import ANSIBLE_VARS
    lower = name.lower()
    ansible = {*ANSIBLE_VARS, *(var for names in CONNECTION.values() for var in names)}
    if name == lower or lower not in ({*taken} if lower.startswith(PREFIX) else ansible):
        return None     # another spelling is the user's own template variable
    then = "" if lower in FLEET_READ_VARS else f" {_inventory_only(lower)}"
    return (f"{shown(name)} is not a variable rosdeploy or Ansible reads (names are case-sensitive): "
            f"did you mean `{lower}`?{then}")


def _compose_passthrough(r: Reader, kp: KeyPath, value: Any) -> Any:
    """`compose:`: not a key rosdeploy renders (_compose_extra), and valid per the Compose schema."""
    value = _compose_extra(r, kp, value)
    if isinstance(value, dict):
        _compose_schema(r, kp, {k: v for k, v in value.items() if k not in MANAGED_COMPOSE})
        _compose_tmpfs(r, kp + ("tmpfs",), value.get("tmpfs"))
        value = _compose_numbers(r, kp, value)
    return value


# How Compose reads a string in a key whose schema type is "number or string" (the string is
# for `${VAR}`): v2 casts it (strconv.ParseInt; go-units' RAMInBytes for a size) and refuses
# the file when it is no number ("failed to cast to expected type"); v1 hands it to docker-py,
# which refuses a string where it wants an int, and reads cpu_quota's and cpu_period's as a
# duration (where "50000" crashes it). Only a number written as one reads the same in both.
_COMPOSE_SIZES = frozenset({"mem_limit", "mem_reservation", "memswap_limit", "shm_size"})
_MICROSECONDS = frozenset({"cpu_quota", "cpu_period", "cpu_rt_runtime", "cpu_rt_period"})
_GO_INT = re.compile(r"[-+]?[0-9]+")     # strconv.ParseInt(s, 10, 64): ASCII digits, no `_`, no spaces
_INT64 = 2**63


@functools.cache
def compose_number_keys() -> Mapping[str, str]:
    """The `compose:` keys the Compose schema types as a number or a string (those rosdeploy
    renders left out) -> how Compose reads the string: "size" or "integer" (`cpus`, the one float, is
    rendered from `resources.cpus`)."""
    known = _compose_schema_data()["definitions"]["service"]["properties"]
    out = {}
    for key, prop in known.items():
        kinds = prop.get("type") if isinstance(prop, dict) else None
        if key not in MANAGED_COMPOSE and isinstance(kinds, list) and "string" in kinds \
                and {"number", "integer"} & set(kinds):
            out[key] = "size" if key in _COMPOSE_SIZES else "integer"
    return out


def _compose_numbers(r: Reader, kp: KeyPath, extra: dict) -> dict:
    """`extra` with the numbers written as strings (`pids_limit: "12"`) written as numbers; a string
    that is none is refused, unless it is an interpolation the robot's Compose fills in."""
    interpolated = r.raw(kp[:-1] + ("compose_interpolate",)) is True
    out = dict(extra)
    for key, kind in compose_number_keys().items():
        value = extra.get(key)
        if key not in extra or isinstance(value, bool) or (interpolated and isinstance(value, str) and "$" in value):
            continue     # a boolean is the schema's to refuse; `${VAR}` is the robot's Compose's to judge
        try:
            out[key] = _compose_number(value, kind, key in _MICROSECONDS)
        except ValueError as exc:
            hint = "" if interpolated or not (isinstance(value, str) and "$" in value) else (
                " (to have the robot's Compose fill in `${VAR}`, set `compose_interpolate: true`)")
            r.error(kp + (key,), f"{shown(value)} is not {exc}: Compose reads {key} as one{hint}")
    return out


def _compose_number(value: Any, kind: str, microseconds: bool = False) -> Any:
    """The value as Compose v1 and v2 both read it; ValueError("what it must be") when they cannot."""
    if kind == "size":
        if isinstance(value, str) and (value != value.strip() or not _size_ok(value)):
            raise ValueError("a size in bytes, e.g. 512m or 1g")
        return value
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    elif isinstance(value, str) and _GO_INT.fullmatch(value):
        value = int(value)
    if not isinstance(value, int) or not -_INT64 <= value < _INT64:
        raise ValueError("a whole number of microseconds, e.g. 950000" if microseconds else "a whole number, e.g. 100")
    return value


def _size_ok(text: str) -> bool:
    try:
        size_bytes(text)
    except ValueError:
        return False
    return True


def _tmpfs_targets(tmpfs: Any) -> list[tuple[KeyPath, str]]:
    """(key path below `tmpfs`, container path) of each entry: `tmpfs` is a string or a list."""
    if isinstance(tmpfs, str):
        return [((), tmpfs.split(":", 1)[0].strip())]
    if not isinstance(tmpfs, list):
        return []
    return [((i,), e.split(":", 1)[0].strip() if isinstance(e, str) else "") for i, e in enumerate(tmpfs)]


def _compose_tmpfs(r: Reader, kp: KeyPath, tmpfs: Any) -> None:
    """`tmpfs: [/dev/shm]` would hide rosdeploy's own mounts (the DDS shared memory, logs, profile);
    one in /proc or /sys stops the container from being created, as a bind mount there does."""
    for where, target in _tmpfs_targets(tmpfs):
        if not target.startswith("/"):
            continue
        if normal_path(target) == "/":     # moby's ValidateTmpfsMountDestination: "destination can't be '/'"
            r.error(kp + where, f"{shown(target)} is the container's root: Docker refuses a tmpfs there (the "
                                "container would not be created); give a folder, e.g. /tmp")
            continue
        taken = managed_mount(target)
        if taken:
            r.error(kp + where,
                    f"{target} is where rosdeploy mounts {taken} itself: a tmpfs there would replace it; "
                    "choose another container path")
            continue
        problem = proc_mount_problem(normal_path(target))
        if problem:
            r.error(kp + where, f"a tmpfs at {problem}" if problem.startswith("/") else problem)


def _compose_schema(r: Reader, kp: KeyPath, extra: dict) -> None:
    from rosdeploy.suggest import did_you_mean
    schema = _compose_schema_data()
    known = schema["definitions"]["service"]["properties"]
    checked = {}
    for key, item in extra.items():
        if isinstance(key, str) and (key in known or key.startswith("x-")):
            checked[key] = item
        else:
            hint = did_you_mean(key, [k for k in known if k not in MANAGED_COMPOSE])
            r.error(kp + (key,), f"unknown compose service key {shown(key)}: {hint or 'see the Compose specification'}"
                                 " (Compose v1 would refuse the file)")
    document = {"services": {"s": checked}}
    if schema_quick.verdict(schema, document) is True:
        return   # valid for certain: no need to import jsonschema (schema_quick.py says why)
    for err in sorted(_compose_validator().iter_errors(document), key=lambda e: list(map(str, e.path))):
        path = tuple(err.path)[2:]
        r.error(kp + path, f"not valid for compose: {err.message[:200]}")


_SCHEMA: list[Any] = []
_VALIDATOR: list[Any] = []


def _compose_schema_data() -> Any:
    """The Compose schema, read once per process (800 lines)."""
    if not _SCHEMA:
        import json
        _SCHEMA.append(json.loads(COMPOSE_SCHEMA.read_text(encoding="utf-8")))
    return _SCHEMA[0]


def _compose_validator() -> Any:
    """Built once per process; jsonschema is imported only when schema_quick cannot vouch for `compose:`."""
    if not _VALIDATOR:
        import jsonschema  # type: ignore[import-untyped]  # no stubs; used through Any
        _VALIDATOR.append(jsonschema.Draft201909Validator(_compose_schema_data()))
    return _VALIDATOR[0]


DOCKER_MIN_HEALTH = 0.001    # dockerd refuses a healthcheck duration under 1ms, other than 0


def _health_period(zero: str | None) -> Convert:
    """A service healthcheck duration. Docker reads 0 as its default (30s for interval and timeout),
    so `interval: 0s` would silently be 30s: refuse it unless `zero` says what 0 means (start_period)."""
    def convert(r: Reader, kp: KeyPath, value: Any) -> Any:
        seconds = _duration(r, kp, value)
        if seconds == 0 and zero is None:
            raise Invalid(f"must be above 0: Docker reads 0 as its default of 30s; write 30s if that is meant, "
                          f"or a duration like 10s; got {_kind(value)}")
        if 0 < seconds < DOCKER_MIN_HEALTH:
            raise Invalid(f"must be 0 ({zero}) or at least 1ms (Docker's least); got {_kind(value)}"
                          if zero else f"must be at least 1ms (Docker's least); got {_kind(value)}")
        return seconds
    return convert


_HEALTHCHECK = {"test": _health_test, "interval": _health_period(None), "timeout": _health_period(None),
                "retries": _integer(1), "start_period": _health_period("no start period")}
_TOPIC = {"name": _string("topic", "ROS topic name (absolute, e.g. /joint_states)"), "min_rate": _positive}
SERVICE = {
    "image": _image, "tag": _tag, "command": _command,
    "environment": _named("env", "environment variable", _text),
    "secrets": _named("env", "environment variable", _string("env", "inventory variable name")),
    "devices": _listof(_string("device", "device name"), "logical device names"),
    "volumes": _volumes,
    "gpu": _boolean, "restart": _restart,
    "resources": _section({"memory": _memory, "cpus": _cpus}),
    "healthcheck": _healthcheck,
    "depends_on": _listof(_string("name", "service name"), "service names"),
    "topics": lambda r, kp, v: _topics(r, kp, v),
    "user": _user,
    "privileged": _boolean, "allow_privileged": _boolean,
    "profiles": _listof(_string("name", "profile name"), "profile names"),
    "compose": _compose_passthrough,
    "compose_interpolate": _boolean,
    "files": _listof(_string("name", "file name (a key of the top-level `files:`)"), "file names"),
}
SECTIONS: dict[str, Mapping[str, Convert]] = {
    "ssh": {"known_hosts": _known_hosts_file, "config": _ssh_config_file,
            "connect_timeout": _positive_duration, "command_timeout": _positive_duration,
            "persist": _duration},
    "ros": {"rmw": _enum("fastdds", "cyclonedds"), "network_mode": _enum("host", "bridge"), "shm_size": _size},
    "logging": {"max_size": _log_size, "max_file": _integer(1), "rotate_every": _rotate_every},
    "preflight": {"min_free_disk_mb": _integer(0)},
    "health": {"timeout": _positive_duration, "stable": _duration, "interval": _positive_duration,
               "topic_window": _positive_duration, "topics_within": _positive_duration,
               "probe_service": _string("name", "service name")},
    "rollout": {"waves": _waves, "max_fail": _max_fail, "forks": _integer(1),
                "order_by": _order_by, "pause": _duration,
                "retry": _positive_duration, "retry_max": _positive_duration, "count_busy": _boolean},
    "rollback": {"auto": _boolean, "fleet": _boolean, "keep_releases": _integer(2),
                 "guard": _enum("revert", "finish", "off"), "guard_margin": _duration},
    "images": {"via": _enum("registry", "ssh"), "max_rate": _rate, "total_rate": _rate,
               "controller_registry": _controller_registry},
}
TOP = {
    "project": _string("name", "project name"),
    "inventory": Reader.local_path,
    "registry": _registry,
    "version": _tag,
    "templates": Reader.local_path,
    "deploy_root": _deploy_root,
    **{name: _section(schema) for name, schema in SECTIONS.items()},
    "services": _named("name", "service", _section(SERVICE, required=("image",))),
    "vars": _named("env", "template variable", _fleet_var),
    "ready": readiness.convert,     # the readiness gate (ready.py)
    "window": windows.convert,      # the maintenance window (window.py)
    "files": _named("name", "file", lambda r, kp, v: _robot_file(r, kp, v)),
}


# ---------------------------------------------------------------- loading

def load_fleet(path: str | Path, *, inventory: str | None = None, version: str | None = None) -> FleetSpec:
    """Read and validate a fleet file. `inventory` (-i) and `version` (--version) override the file's keys.
    The spec's `warnings` are the file's: a number YAML 1.1 reads as octal (`017`, read as 15, as
    Ansible reads it: a port or an id the user did not mean; yamlsrc._octal_warning)."""
    found: list[Problem] = []
    try:
        doc = yamlsrc.load(path, warnings=found)
    except InputError as exc:
        raise FleetSpecError(exc.problems) from exc
    r = Reader(doc)
    if not isinstance(doc.data, dict):
        raise FleetSpecError([doc.problem((), "the fleet file must be a mapping with at least project, inventory, "
                                              "registry, version and services (see the README (The fleet file))")])
    r.scan_control_chars(doc.data)
    required = ("project", "services") + (() if inventory else ("inventory",)) + (() if version else ("version",))
    top = _section(TOP, required=required)(r, (), doc.data)
    _check_paths(r, top, inventory_overridden=bool(inventory))
    top.update(_overrides(r, inventory, version))
    _check_services(r, top)
    if isinstance(top.get("ready"), readiness.ReadyPolicy) and isinstance(top.get("services"), dict):
        readiness.check_services(top["ready"], dict.fromkeys(r.names(("services",), top["services"])), r, ("ready",))
    if r.problems:
        raise FleetSpecError(sorted(r.problems, key=lambda p: (p.file != doc.path, p.line or 0)))
    return dataclasses.replace(_build(doc, top), warnings=tuple(found))


def _overrides(r: Reader, inventory: str | None, version: str | None) -> dict[str, Any]:
    """-i and --version: checked like the keys they replace, located on the command line."""
    out: dict[str, Any] = {}
    if inventory:
        out["inventory"] = os.path.abspath(os.path.expanduser(os.path.expandvars(inventory)))
        if not _exists(out["inventory"]):
            hint = (" (Ansible's host list, `-i host1,host2,`, is not read: write an inventory file)"
                    if "," in inventory else "")
            r.problems.append(Problem("--inventory", None, "", f"{inventory} {_missing(out['inventory'])}: fix the -i "
                                                              f"path{hint}"))
    if version is not None:
        cli = Reader(Doc("--version", None))
        cli.take(_tag, ("version",), version, out, "version")
        r.problems.extend(cli.problems)
    return out


def _check_paths(r: Reader, top: dict, inventory_overridden: bool) -> None:
    inv = top.get("inventory")
    if not inventory_overridden and isinstance(inv, str) and not _exists(inv):
        r.error(("inventory",), f"the inventory {_as_written(r, 'inventory', inv)} {_missing(inv)}: fix the path "
                                "(relative to the fleet file) or pass -i")
    tpl = top.get("templates")
    if isinstance(tpl, str) and not _exists(tpl, folder=True):
        r.error(("templates",), f"{_as_written(r, 'templates', tpl)} is not a directory: point `templates:` at a "
                                "folder of *.j2 overrides (relative to the fleet file) or remove the key")


def _exists(path: str, folder: bool = False) -> bool:
    """Path.exists/is_dir, where a name too long for the filesystem is "no" rather than an OSError."""
    try:
        return Path(path).is_dir() if folder else Path(path).exists()
    except OSError:
        return False


def _missing(path: str) -> str:
    """Why a path that is not there is not: a link that leads back to itself reads as missing."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "is a symbolic link loop (a link that leads back to itself, directly or through other links)"
    return "does not exist"


def _as_written(r: Reader, key: str, expanded: str) -> str:
    """A path as the file wrote it when it used $VARS: an environment value never reaches a message."""
    written = str(r.doc.data.get(key, expanded))
    return repr(written) if "$" in written else expanded


def _check_services(r: Reader, top: dict) -> None:
    services = top.get("services")
    if not isinstance(services, dict):
        return
    names = r.names(("services",), services)   # a service whose value was refused is still declared
    if not names and "services" in r.doc.data and not r.raw(("services",)):   # a bad name is reported as such
        r.error(("services",), "declares no service: add at least one, e.g. `driver: {image: acme/amr-driver}`")
    for name, svc in services.items():
        _check_service(r, ("services", name), svc, names, top.get("registry"))
    health: dict = top["health"] if isinstance(top.get("health"), dict) else {}
    probe = health.get("probe_service")
    if isinstance(probe, str) and probe not in names:
        r.error(("health", "probe_service"), f"no service is named `{probe}`{_did_you_mean(probe, names)}")
    elif isinstance(probe, str) and _profiled(r, probe):
        r.error(("health", "probe_service"), f"`{probe}` has profiles, and a deploy never starts a service with "
                                             "profiles: the gate's probe would find no container; name a service "
                                             "without profiles")
    _check_gate_can_pass(r, health)
    _check_cycles(r, services)
    _check_port_clashes(r, services)
    _check_file_refs(r, services, top.get("files"))


# health keys that count from the switch, as `timeout` does, and what each is
def _check_gate_can_pass(r: Reader, health: dict) -> None:
    """`stable` and `timeout` both count from the switch: a stable window as long as the whole gate
    fails every deploy, and rolls it back. (`topics_within` and `topic_window` are bounds, not
    waits: a topic that appears, or proves its rate, early ends them; at or past `timeout` they
    only turn the early failure off.)"""
    stable, timeout = (health.get(k, getattr(HealthPolicy, k)) for k in ("stable", "timeout"))
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (stable, timeout))
    if numbers and stable >= timeout:
        r.error(("health", "stable" if "stable" in health else "timeout"),
                f"health.stable ({stable:g} s) is not shorter than health.timeout ({timeout:g} s), which counts "
                "from the switch too: no release could pass the gate; make stable shorter than timeout")


def _reserved_env(name: str) -> str:
    if name == "ROS_LOG_DIR":
        return ("ROS_LOG_DIR is /ros_log, set by rosdeploy: the robot's logs/<service> folder, which its "
                "logrotate rotates; logs written elsewhere fill the container unrotated: remove it here")
    return f"{name} is set per robot by rosdeploy (from the inventory and `ros:`); remove it here"


def _check_service(r: Reader, kp: KeyPath, svc: dict, names: list[str], registry: Any) -> None:
    _check_image_registry(r, kp + ("image",), svc.get("image"), registry)
    env = r.names(kp + ("environment",), svc.get("environment"))
    for name in env:
        if name in RESERVED_ENV:
            r.error(kp + ("environment", name), _reserved_env(name))
    for name in r.names(kp + ("secrets",), svc.get("secrets")):
        if name in RESERVED_ENV:
            r.error(kp + ("secrets", name), _reserved_env(name))
        elif name in env:
            r.error(kp + ("secrets", name), f"{name} is also in `environment`: keep it in one of the two")
    for i, dep in _deps(r, kp[-1]):
        _check_dependency(r, kp + ("depends_on", i), kp[-1], dep, names, r.raw(("services", dep)))
    if isinstance(svc.get("compose"), dict):
        _check_compose_conflicts(r, kp, svc, names)


# Sysctls a container may set in its own IPC, network or UTS namespace (runc's validator); the
# rest are the robot's kernel's, which runc refuses to touch from a container. Host networking
# shares the host's network and UTS namespaces.
IPC_SYSCTLS = ("kernel.shm", "kernel.msg", "kernel.sem", "fs.mqueue.")
HOST_NET_SYSCTLS = ("net.", "kernel.domainname", "kernel.hostname")


def _check_compose_conflicts(r: Reader, kp: KeyPath, svc: dict, names: list[str]) -> None:
    """`compose:` keys Docker or Compose refuse beside what rosdeploy renders: each passes the
    schema alone, and the deploy would fail at the robot (`check` is where to learn it)."""
    extra, where = svc["compose"], kp + ("compose",)
    if svc.get("compose_interpolate") is True:     # `${VAR}` is the robot's to fill in: judge the rest
        extra = _literal(extra)
    written = svc.get("resources")
    resources: dict = written if isinstance(written, dict) else {}
    for key in ("cpu_quota", "cpu_period"):
        if key in extra and resources.get("cpus") is not None:
            r.error(where + (key,), f"Docker refuses {key} beside `resources.cpus` (its Nano CPUs): use one of them")
    memory = _bytes_or_none(resources.get("memory"))
    reserved = _bytes_or_none(extra.get("mem_reservation"))
    if memory and reserved and reserved > memory:
        r.error(where + ("mem_reservation",), "above `resources.memory`: Docker refuses a reservation over the "
                                              "limit; lower it")
    swap = _bytes_or_none(extra.get("memswap_limit"))
    if memory and swap and 0 < swap < memory:
        r.error(where + ("memswap_limit",), "below `resources.memory`: memory plus swap cannot be less than "
                                            "memory (Docker refuses it); raise it, or -1 for unlimited swap")
    host_net = r.raw(("ros", "network_mode")) in (None, "host")
    for at, name in sysctl_names(extra.get("sysctls")):
        refused = sysctl_refusal(name, host_net, extra.get("ipc") == "host")
        if refused == "kernel":
            r.error(where + ("sysctls", at), f"{name} is not a namespaced sysctl: runc refuses to set the robot's "
                                             "kernel from a container; set it on the robot")
        elif refused == "host-net":
            r.error(where + ("sysctls", at), f"Docker refuses {name} in the host's namespaces "
                                             "(`ros.network_mode: host`): it needs the container's own; "
                                             "set it on the robot")
        elif refused == "ipc-host":
            r.error(where + ("sysctls", at), f"Docker refuses {name} with `ipc: host`: it needs the container's "
                                             "own IPC namespace")
    mac = extra.get("mac_address")
    if isinstance(mac, str) and (host_net or not _MAC.fullmatch(mac)):
        r.error(where + ("mac_address",), "Docker refuses a MAC address on host networking (`ros.network_mode: "
                                          "host`): remove it" if host_net else
                f"{shown(mac)} is not a MAC address: write six hex pairs, e.g. 02:42:ac:11:00:02")
    _check_tmpfs_at_volumes(r, kp, extra.get("tmpfs"))
    _check_compose_values(r, where, extra)
    _check_compose_formats(r, where, extra)
    links = extra.get("links")
    for key in ("links", "external_links"):
        if host_net and extra.get(key):
            r.error(where + (key,), "Docker refuses links on host networking (`ros.network_mode: host`: \"host "
                                    "type networking can't be used with links\"); on the host's network the "
                                    "services reach each other at localhost: remove it")
    for i, link in enumerate(links if isinstance(links, list) and not host_net else []):
        target = str(link).split(":", 1)[0]
        if target == kp[-1]:
            r.error(where + ("links", i), "a service cannot link to itself (Compose refuses the cycle): remove it")
        elif target not in names:
            r.error(where + ("links", i), f"no service is named `{target}`{_did_you_mean(target, names)}")
    for key in ("ipc", "pid"):
        shared = extra.get(key)
        if not (isinstance(shared, str) and shared.startswith("service:")):
            continue
        target = shared[len("service:"):]
        if target == kp[-1]:
            r.error(where + (key,), f"a service cannot share its own {key} namespace (Compose refuses the cycle): "
                                    "remove it")
        elif target not in names:    # Compose refuses the file, as for links
            r.error(where + (key,), f"no service is named `{target}`{_did_you_mean(target, names)}")


# What Docker takes on Linux where the Compose schema allows any string (go-units' ulimits, with
# `as` disabled there; moby's signal map, aliases and real-time signals included)
_ULIMITS = frozenset({"core", "cpu", "data", "fsize", "locks", "memlock", "msgqueue", "nice", "nofile", "nproc",
                      "rss", "rtprio", "rttime", "sigpending", "stack"})
_SHARED_NS = re.compile(r"host|container:.+|service:.+")
_SHARED_NAMES = "host, container:NAME, service:NAME"
# moby's IpcMode.Valid: "" is the daemon's default (private or shareable)
_IPC_MODES = re.compile(r"|none|private|shareable|host|container:.+|service:.+")
_SIGNALS = frozenset("ABRT ALRM BUS CHLD CLD CONT FPE HUP ILL INT IO IOT KILL PIPE POLL PROF PWR QUIT SEGV STKFLT "
                     "STOP SYS TERM TRAP TSTP TTIN TTOU UNUSED URG USR1 USR2 VTALRM WINCH XCPU XFSZ".split())
_RT_SIGNAL = re.compile(r"RTMIN(\+(?:[1-9]|1[0-5]))?|RTMAX(-(?:[1-9]|1[0-4]))?")


def _literal(value: Any) -> Any:
    """`value` without the strings that hold a `$` (Compose interpolates them on the robot)."""
    if isinstance(value, dict):
        return {k: _literal(v) for k, v in value.items() if not (isinstance(v, str) and "$" in v)}
    if isinstance(value, list):
        return [_literal(v) for v in value if not (isinstance(v, str) and "$" in v)]
    return value


def _is_signal(text: str) -> bool:
    name = text.upper().removeprefix("SIG")
    return text.isdigit() or name in _SIGNALS or bool(_RT_SIGNAL.fullmatch(name))


def _check_compose_values(r: Reader, where: KeyPath, extra: dict) -> None:
    """Values the Compose schema lets through and Docker refuses at the robot."""
    import ipaddress
    if isinstance(extra.get("working_dir"), str) and not extra["working_dir"].startswith("/"):
        r.error(where + ("working_dir",), "must be an absolute path in the container (Docker refuses a relative one)")
    for i, server in enumerate(extra["dns"] if isinstance(extra.get("dns"), list) else []):
        try:
            ipaddress.ip_address(str(server))
        except ValueError:
            r.error(where + ("dns", i), f"{shown(server)} is not an IP address: Docker takes DNS servers by address")
    isolation = extra.get("isolation")
    if isinstance(isolation, str) and isolation.lower() not in ("", "default"):
        r.error(where + ("isolation",), "only `default` exists on Linux (hyperv and process are Windows'): remove it")
    for key, modes, names in (("pid", _SHARED_NS, _SHARED_NAMES), ("userns_mode", _SHARED_NS, _SHARED_NAMES),
                              ("ipc", _IPC_MODES, "none, private, shareable, " + _SHARED_NAMES)):
        value = extra.get(key)
        if isinstance(value, str) and not modes.fullmatch(value):
            r.error(where + (key,), f"{shown(value)} is none of {names} (Docker's names are lower case)")
    storage = extra.get("storage_opt")
    size = storage.get("size") if isinstance(storage, dict) else None
    if isinstance(size, str) and not _RATE.fullmatch(size):
        # the storage driver reads it with go-units' RAMInBytes at create (`20GiB`, `10 GB`): "invalid size"
        r.error(where + ("storage_opt", "size"), f"{shown(size)} is not a size in bytes, e.g. 10g (Docker refuses it)")
    stop = extra.get("stop_signal")
    if isinstance(stop, str) and not _is_signal(stop):
        r.error(where + ("stop_signal",), f"{shown(stop)} is no signal: e.g. SIGINT (what ros2 launch handles)")
    limits = extra.get("ulimits")
    for name, limit in (limits.items() if isinstance(limits, dict) else []):
        if name not in _ULIMITS:
            close = suggest(str(name), sorted(_ULIMITS))
            r.error(where + ("ulimits", name), f"no ulimit Docker sets is named {shown(name)}"
                                               + (f": did you mean `{close[0]}`?" if close else ""))
        elif isinstance(limit, dict) and all(isinstance(limit.get(k), int) for k in ("soft", "hard")):
            _check_ulimit(r, where + ("ulimits", name), limit["soft"], limit["hard"])


# Forms the Compose schema's `format`s stand for (fleet.py checks no format): Go's net.ParseMAC
# (a little looser: no count of octets), time.ParseDuration, and go-units' RAMInBytes for a rate.
_MAC = re.compile(r"[0-9A-Fa-f]{2}(?::[0-9A-Fa-f]{2}){5,19}|[0-9A-Fa-f]{2}(?:-[0-9A-Fa-f]{2}){5,19}"
                  r"|[0-9A-Fa-f]{4}(?:\.[0-9A-Fa-f]{4}){2,9}")
_GO_DURATION = re.compile(r"[-+]?(?:0|(?:(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:ns|us|µs|μs|ms|s|m|h))+)")
_RATE = re.compile(r"[0-9]+(?:\.[0-9]+)* ?[kKmMgGtTpP]?[iI]?[bB]?")
_PORT_PART = re.compile(r"([0-9]+)(?:-([0-9]+))?")


def _check_compose_formats(r: Reader, where: KeyPath, extra: dict) -> None:
    """Values in a shape the schema allows and Compose or Docker refuses (probe J, item 11)."""
    swappiness = extra.get("mem_swappiness")
    if isinstance(swappiness, int) and not isinstance(swappiness, bool) and not -1 <= swappiness <= 100:
        r.error(where + ("mem_swappiness",), "must be 0-100 (Docker's range; -1 leaves the default)")
    grace = extra.get("stop_grace_period")
    if isinstance(grace, str) and not _GO_DURATION.fullmatch(grace.strip()):
        r.error(where + ("stop_grace_period",), f"{shown(grace)} is not a duration: e.g. 10s, 1m30s")
    # cpu_rt_runtime and cpu_rt_period: a whole number, as each key of compose_number_keys (_compose_numbers)
    for i, port in enumerate(extra["ports"] if isinstance(extra.get("ports"), list) else []):
        problem = (short_port_problem(port) if isinstance(port, str)
                   else long_port_problem(port) if isinstance(port, dict) else None)
        if any(n > 65535 for n in _port_numbers(port)):
            r.error(where + ("ports", i), f"{shown(port)}: a port number is at most 65535")
        elif problem:
            r.error(where + ("ports", i), f"{shown(port)}: {problem} (Compose refuses it)")
    for i, port in enumerate(extra["expose"] if isinstance(extra.get("expose"), list) else []):
        problem = _port_range_problem(str(port).split("/", 1)[0].strip(), "port")
        if problem:    # dockerd's verifyContainerSettings: "invalid port specification"
            r.error(where + ("expose", i), f"{shown(port)}: {problem} (Docker refuses it)")
    _check_extra_hosts(r, where + ("extra_hosts",), extra.get("extra_hosts"))
    cpuset = extra.get("cpuset")
    if isinstance(cpuset, str) and cpuset and not _cpu_list_ok(cpuset):     # "" sets none
        r.error(where + ("cpuset",), f"{shown(cpuset)} is not a list of CPUs: e.g. 0-3 or 0,2 (Docker refuses it)")
    blkio = extra.get("blkio_config")
    for key, limits in (blkio.items() if isinstance(blkio, dict) else []):
        for i, limit in enumerate(limits if isinstance(limits, list) else []):
            rate = limit.get("rate") if isinstance(limit, dict) else None
            if isinstance(rate, str) and not (_RATE if key.endswith("_bps") else _ASCII_DIGITS).fullmatch(rate):
                what = "a size in bytes per second, e.g. 10mb" if key.endswith("_bps") else "a whole number"
                r.error(where + ("blkio_config", key, i, "rate"), f"{shown(rate)} is not {what} (Compose refuses it)")


_ASCII_DIGITS = re.compile(r"[0-9]+")
PORT_PROTOCOLS = ("tcp", "udp", "sctp")


def short_port_problem(port: str) -> str | None:
    """Why Compose v2 refuses a short-syntax `ports:` entry `[IP:][HOST[-HOST]:]CONTAINER[-CONTAINER][/PROTO]`,
    or None: go-connections' nat.ParsePortSpec, as compose-go calls it (v1 refuses fewer of them)."""
    spec, _, proto = port.partition("/")     # Go trims no space anywhere here: " 80" is refused
    if proto and proto.lower() not in PORT_PROTOCOLS:
        return f"{shown(proto)} is not a protocol: tcp, udp or sctp"
    ip, host, container = _port_parts(spec)
    if ip and _go_ip(ip) is None:
        return f"{shown(ip)} is not an IP address"
    problem = _port_range_problem(container, "container port") or (host and _port_range_problem(host, "host port"))
    if problem:
        return problem
    if _PORT_PART.fullmatch(container).group(1).lstrip("0") == "":   # type: ignore[union-attr]
        return "the container port is missing (0)"
    ranges = [_range_size(p) for p in (host, container) if p]
    if len(ranges) == 2 and ranges[1] > 1 and ranges[0] != ranges[1]:
        return f"host ports {host} and container ports {container} are ranges of different lengths"
    return None


def long_port_problem(port: Mapping[str, Any]) -> str | None:
    """Why Compose or Docker refuses a long-syntax `ports:` entry, or None: the short syntax's checks
    (short_port_problem) on its `protocol`, `target` and `published` (a port or a range, 0 a free one).
    A number over 65535 is reported by the caller, for both syntaxes."""
    proto, target, published = port.get("protocol"), port.get("target"), port.get("published")
    if isinstance(proto, str) and proto.lower() not in PORT_PROTOCOLS:
        return f"{shown(proto)} is not a protocol: tcp, udp or sctp"
    if isinstance(target, int) and not isinstance(target, bool) and target < 1:
        return f"the container port must be from 1 to 65535, not {target}"
    if isinstance(published, int) and not isinstance(published, bool) and published < 0:
        return f"the host port must be from 0 to 65535, not {published}"
    if isinstance(published, str):
        return _port_range_problem(published, "host port")
    return None


def _port_parts(spec: str) -> tuple[str, str, str]:
    """(ip, host, container) as nat's splitParts cuts them: the IP is all before the last two `:`s."""
    parts = spec.split(":")
    if len(parts) == 1:
        return "", "", parts[0]
    if len(parts) == 2:
        return "", parts[0], parts[1]
    ip = ":".join(parts[:-2])
    return (ip[1:-1] if ip.startswith("[") and ip.endswith("]") else ip), parts[-2], parts[-1]


def _go_ip(text: str) -> Any:
    """The address Go's net.ParseIP reads, or None: no zone (`%eth0`), no leading zeros (Python's rule too)."""
    import ipaddress
    try:
        return None if "%" in text else ipaddress.ip_address(text)
    except ValueError:
        return None


def _port_range_problem(text: str, what: str) -> str | None:
    """nat.ParsePortRange: a port or a low-high range, each 16 bits (above 65535 is reported apart)."""
    found = _PORT_PART.fullmatch(text)
    if not found:
        return f"{shown(text)} is not a {what} (a number or a range like 8000-8010)"
    low, high = (int(n[:7]) for n in (found.group(1), found.group(2) or found.group(1)))
    if max(low, high) > 65535:
        return f"a {what} is at most 65535"
    if high < low:
        return f"the {what} range {text} runs backwards: write the lower port first"
    return None


def _range_size(text: str) -> int:
    low, _, high = text.partition("-")
    return int(high or low) - int(low) + 1


def _check_extra_hosts(r: Reader, kp: KeyPath, hosts: Any) -> None:
    """Each entry maps a name to an IP address (or Docker's `host-gateway`): Compose v2 refuses an entry
    without one, and dockerd's ValidateExtraHost any address it cannot parse, when it starts the container."""
    if isinstance(hosts, dict):
        entries = [(name, str(name), "" if ip is None else str(ip)) for name, ip in hosts.items()]
    elif isinstance(hosts, list):
        entries = [(i, *_host_entry(str(e))) for i, e in enumerate(hosts)]
    else:
        return
    for at, name, ip in entries:
        ip = ip.strip()
        ip = ip[1:-1] if ip.startswith("[") and ip.endswith("]") else ip
        if ip != "host-gateway" and _go_ip(ip) is None:
            given = f"to {shown(ip)}, which is no IP address" if ip else "to no IP address"
            r.error(kp + (at,), f"{shown(name)} maps {given}: write NAME:IP, e.g. robot-base:10.0.0.2 (or "
                                "NAME:host-gateway)")


def _host_entry(entry: str) -> tuple[str, str]:
    """(name, address) of `NAME:IP` or `NAME=IP` (Compose's two spellings; an IPv6 address holds `:`s)."""
    cut = min((i for i in (entry.find("="), entry.find(":")) if i >= 0), default=-1)
    return (entry, "") if cut < 0 else (entry[:cut], entry[cut + 1:])


def _cpu_list_ok(text: str) -> bool:
    """dockerd's parsers.ParseUintList: `0-3,5`, each range low to high."""
    for part in text.split(","):
        found = _PORT_PART.fullmatch(part)
        if not found or (found.group(2) and int(found.group(2)[:7]) < int(found.group(1)[:7])):
            return False
    return True


def _port_numbers(port: Any) -> list[int]:
    """The port numbers of a `ports:` entry: short syntax `[IP:][HOST[-HOST]:]CONTAINER[-CONTAINER][/PROTO]`,
    a number, or the long form's target and published."""
    if isinstance(port, dict):
        return [v for v in (port.get("target"), port.get("published")) if isinstance(v, int)]
    if isinstance(port, (int, float)) and not isinstance(port, bool):
        return [int(port)]
    parts = str(port).split("/", 1)[0].rsplit(":", 2)
    numbers = []
    for part in parts[-2:] if len(parts) > 1 else parts:
        found = _PORT_PART.fullmatch(part.strip())
        if found:    # a number of more than 6 digits is too big; int() of 5,000 digits raises
            numbers += [int(n) if len(n) <= 6 else 10**6 for n in found.groups() if n]
    return numbers


# One published host port: (service, index in its `ports`, protocol, host IP ("" is every address), low, high)
Published = tuple[str, int, str, str, int, int]


def _check_port_clashes(r: Reader, services: dict) -> None:
    """Two services publishing one host port (bridge networking): Compose takes the file, and the second
    container fails at `up` ("port is already allocated"). Services with profiles never start in a deploy."""
    if r.raw(("ros", "network_mode")) != "bridge":
        return    # on the host's network `ports` are not published at all
    seen: list[Published] = []
    for name, svc in services.items():
        if not isinstance(svc, dict) or not isinstance(svc.get("compose"), dict) or _profiled(r, name):
            continue
        extra = _literal(svc["compose"]) if svc.get("compose_interpolate") is True else svc["compose"]
        ports = extra.get("ports")
        mine = [p for i, port in enumerate(ports if isinstance(ports, list) else [])
                if (p := _published(name, i, port))]
        for port in mine:
            first = next((other for other in seen if _same_host_port(port, other)), None)
            if first:
                r.error(("services", name, "compose", "ports", port[1]),
                        f"host port {_port_text(port)} is already published by service `{first[0]}` "
                        f"(its compose.ports[{first[1]}]): the second container would not start (\"port is "
                        "already allocated\"); publish another host port")
        seen += mine


def _published(service: str, i: int, port: Any) -> Published | None:
    """The host ports a well-formed `ports:` entry publishes, or None (none given: Docker picks a free one)."""
    if isinstance(port, dict):
        host, ip, proto = port.get("published"), str(port.get("host_ip") or ""), str(port.get("protocol") or "tcp")
    elif isinstance(port, str) and not short_port_problem(port) and not any(n > 65535 for n in _port_numbers(port)):
        spec, _, proto = port.strip().partition("/")
        ip, host, _ = _port_parts(spec)
    else:
        return None
    found = _PORT_PART.fullmatch(str(host).strip()) if isinstance(host, (str, int)) else None
    if not found or isinstance(host, bool):
        return None
    low = int(found.group(1)[:7])
    high = int((found.group(2) or found.group(1))[:7])
    return service, i, (proto or "tcp").lower(), ip, low, high


def _same_host_port(a: Published, b: Published) -> bool:
    """One protocol, overlapping ports and addresses: an unspecified address (none, 0.0.0.0, ::) takes
    the port on every address of its family, where Linux refuses a second socket on a specific one."""
    if a[2] != b[2] or a[5] < b[4] or b[5] < a[4]:
        return False
    if not a[3] or not b[3]:     # no address given: 0.0.0.0 and [::] both
        return True
    first, second = _go_ip(a[3]), _go_ip(b[3])
    if first is None or second is None:     # not an address (the long form's host_ip is not checked here)
        return a[3] == b[3]
    if first.version != second.version:
        return False
    return first == second or first.is_unspecified or second.is_unspecified


def _port_text(port: Published) -> str:
    ports = str(port[4]) if port[4] == port[5] else f"{port[4]}-{port[5]}"
    return f"{port[3]}:{ports}/{port[2]}" if port[3] else f"{ports}/{port[2]}"


def _check_ulimit(r: Reader, kp: KeyPath, soft: int, hard: int) -> None:
    """-1 is unlimited (go-units' ParseUlimit): a soft limit may not pass its hard one."""
    if hard != -1 and (soft == -1 or soft > hard):
        r.error(kp, "soft is above hard: Docker refuses it (-1 is unlimited)")


def path_too_long(path: str, example: str) -> str | None:
    """Why Linux cannot take `path` (ENAMETOOLONG where Docker, udev or render use it), or None."""
    size = len(path.encode())
    if size <= MAX_PATH and max(len(name.encode()) for name in path.split("/")) <= MAX_PATH_NAME:
        return None
    unit = "characters" if path.isascii() else "bytes"
    return (f"a path of {size} {unit}: Linux allows {MAX_PATH}, and {MAX_PATH_NAME} for each name in it; "
            f"shorten it, e.g. {example}")


def sysctl_refusal(name: str, host_net: bool, ipc_host: bool) -> str:
    """Why runc or Docker refuse to set sysctl `name` in a container: "kernel" (not namespaced: the
    robot's own), "host-net" (a network one on host networking), "ipc-host" (an IPC one with
    `ipc: host`); "" when it is set. The fleet's `compose:` and a rendered compose.yml alike."""
    if not name.startswith(IPC_SYSCTLS + HOST_NET_SYSCTLS):
        return "kernel"
    if name.startswith(HOST_NET_SYSCTLS) and host_net:
        return "host-net"
    if name.startswith(IPC_SYSCTLS) and ipc_host:
        return "ipc-host"
    return ""


def sysctl_names(sysctls: Any) -> list[tuple[str | int, str]]:
    """(key path item, sysctl name) of compose's mapping or `name=value` list form."""
    if isinstance(sysctls, dict):
        return [(name, str(name)) for name in sysctls]
    if isinstance(sysctls, list):
        return [(i, item.split("=", 1)[0].strip()) for i, item in enumerate(sysctls) if isinstance(item, str)]
    return []


def _bytes_or_none(value: Any) -> int | None:
    try:
        return size_bytes(value) if isinstance(value, (str, int)) and not isinstance(value, bool) else None
    except ValueError:
        return None


def _check_tmpfs_at_volumes(r: Reader, kp: KeyPath, tmpfs: Any) -> None:
    """A tmpfs where a bind mount of the service goes: compose refuses the duplicate mount point."""
    mounted = {_mount_target(m) for _, m in r.items(kp + ("volumes",))
               if isinstance(m, str) and m.count(":") >= 1 and m.split(":")[1].startswith("/")}
    for where, target in _tmpfs_targets(tmpfs):
        if target.startswith("/") and normal_path(target) in mounted:
            r.error(kp + ("compose", "tmpfs") + where,
                    f"{target} is also a target of `volumes`: one container path takes one mount; change one")


def _deps(r: Reader, service: str) -> list[tuple[int, str]]:
    """(index, name) of a service's depends_on entries that are valid names."""
    return [(i, dep) for i, dep in r.items(("services", service, "depends_on")) if isinstance(dep, str)]


def _check_image_registry(r: Reader, kp: KeyPath, image: Any, registry: Any) -> None:
    if not isinstance(image, str):
        return
    own = _has_registry_host(image)
    if own and isinstance(registry, str):
        r.error(kp, f"the image names its own registry ({image.split('/')[0]}) while `registry: {registry}` is set: "
                    "drop the host from the image, or drop `registry:` and fully qualify every image")
    elif not own and isinstance(registry, str) and _too_long_under(registry, image):
        r.error(kp, _long_image_name(f"{registry}/{image.split('@')[0]}"))
    elif not own and "registry" not in r.doc.data:
        r.error(kp, f"no `registry:` is set and {shown(image)} has no registry host: add a top-level "
                    f"`registry: registry.local:5000`, or write the full ref, e.g. docker.io/{image}")


def _too_long_under(registry: str, image: str) -> bool:
    """The name the robot pulls is `registry/image`; an image too long alone was refused when read."""
    name = image.split("@")[0]
    return len(name) <= MAX_IMAGE_NAME < len(registry) + 1 + len(name)


def _check_dependency(r: Reader, kp: KeyPath, name: str, dep: str, names: list[str], written: Any) -> None:
    """`written`: the depended-on service as the file has it (its healthcheck may have been refused)."""
    if dep == name:
        r.error(kp, f"`{name}` cannot depend on itself; remove it from depends_on")
    elif dep not in names:
        r.error(kp, f"no service is named `{dep}`{_did_you_mean(dep, names)}")
    elif isinstance(written, dict) and "healthcheck" not in written:
        r.error(kp, f"`{dep}` has no healthcheck, so it never becomes healthy and `{name}` (which waits for "
                    f"service_healthy) would never start: give `{dep}` a healthcheck (or `healthcheck: image`)")
    elif _profiled(r, dep) and not r.raw(("services", name, "profiles")):
        r.error(kp, f"`{dep}` has profiles, and a deploy never starts a service with profiles: `{name}` would "
                    f"wait for it forever; remove `{dep}`'s profiles or this dependency")


def _profiled(r: Reader, service: str) -> bool:
    """Does the service declare profiles (well-formed ones: bad names were reported already)?"""
    kp = ("services", service, "profiles")
    return bool(r.raw(kp)) and kp not in r.refused


def _check_cycles(r: Reader, services: dict) -> None:
    graph = {n: [d for _, d in _deps(r, n) if d in services and d != n] for n in services}
    state: dict[str, int] = {}

    def visit(node: str, trail: list[str]) -> None:
        state[node] = 1
        for dep in graph[node]:
            if state.get(dep) == 1:
                loop = trail[trail.index(dep):] + [dep] if dep in trail else [node, dep]
                r.error(("services", node, "depends_on"), f"dependency cycle {' -> '.join(loop)}: "
                                                           "compose cannot start any of them; break the cycle")
            elif dep not in state:
                visit(dep, trail + [dep])
        state[node] = 2

    for node in graph:
        if node not in state:
            visit(node, [node])


def suggest(word: str, choices: Iterable[str]) -> list[str]:
    """The closest choice (difflib), or one the word abbreviates (`shm` -> `shm_size`)."""
    choices = list(choices)
    close = difflib.get_close_matches(word, choices, n=1)
    return close or [c for c in choices if len(word) >= 3 and c.startswith(word)][:1]


def _did_you_mean(word: str, choices: Iterable[str]) -> str:
    close = suggest(word, choices)
    return f": did you mean `{close[0]}`?" if close else f"; the services are: {', '.join(choices)}"


# --------------------------------------------------------------- building

def _build(doc: Doc, top: dict) -> FleetSpec:
    ssh, ros, logging = (top.get(k, {}) for k in ("ssh", "ros", "logging"))
    health, rollout, rollback = (top.get(k, {}) for k in ("health", "rollout", "rollback"))
    return FleetSpec(
        path=doc.path, project=top["project"], inventory=top["inventory"], registry=top.get("registry", ""),
        version=top["version"],
        services=tuple(_service(n, s, top["version"]) for n, s in top["services"].items()),
        rmw=ros.get("rmw", "fastdds"), network_mode=ros.get("network_mode", "host"),
        shm_size=ros.get("shm_size", "512m"),
        log_max_size=logging.get("max_size", "10m"), log_max_file=logging.get("max_file", 3),
        log_rotate_every=logging.get("rotate_every", rotation.DEFAULT_EVERY),
        templates=top.get("templates"), deploy_root=top.get("deploy_root", "~/rosdeploy"),
        known_hosts=ssh.get("known_hosts"), ssh_config=ssh.get("config"),
        connect_timeout=ssh.get("connect_timeout", 10.0), command_timeout=ssh.get("command_timeout", 600.0),
        ssh_persist=ssh.get("persist", 60.0),
        min_free_disk_mb=top.get("preflight", {}).get("min_free_disk_mb", 1024),
        health=HealthPolicy(**health),
        rollout=RolloutPolicy(**rollout),   # waves: a tuple already (_listof)
        rollback=RollbackPolicy(**rollback),
        images=ImagePolicy(**top.get("images", {})),
        vars=frozen_map(top.get("vars")),
        ready=top.get("ready") or None, window=top.get("window") or None,
        files=tuple(RobotFile(name=n, **f) for n, f in sorted((top.get("files") or {}).items())),
        lines=frozen_map(doc.lines),
    )


def _service(name: str, d: dict, version: str) -> Service:
    healthcheck = d.get("healthcheck")
    resources = d.get("resources", {})
    return Service(
        name=name, image=d["image"].split("@")[0], tag=d.get("tag", version), command=d.get("command"),
        digest=d["image"].partition("@")[2] or None,
        environment=frozen_map(d.get("environment")), secret_env=frozen_map(d.get("secrets")),
        devices=d.get("devices", ()), volumes=tuple(d.get("volumes", ())), gpu=d.get("gpu", False),
        restart=d.get("restart", "unless-stopped"),
        memory=resources.get("memory"), cpus=resources.get("cpus"),
        healthcheck=healthcheck if isinstance(healthcheck, HealthCheck) else None,
        healthcheck_from_image=healthcheck == HEALTH_FROM_IMAGE,
        depends_on=d.get("depends_on", ()), topics=d.get("topics", ()), user=d.get("user"),
        privileged=d.get("privileged", False), allow_privileged=d.get("allow_privileged", False),
        profiles=d.get("profiles", ()), extra=frozen_map(d.get("compose")),
        compose_interpolate=d.get("compose_interpolate", False), files=d.get("files", ()),
    )


FILE_KINDS = ("template", "copy", "var")
_FILE_SOURCE_RE = re.compile(r"[A-Za-z0-9_.@+{}' |-]+(/[A-Za-z0-9_.@+{}' |-]+)*")


def _robot_file(r: Reader, kp: KeyPath, value: Any) -> Any:
    """`files: {NAME: {template|copy|var: SOURCE, target: /in/container, secret: bool}}`."""
    d = _section({**{k: _string() for k in FILE_KINDS}, "target": _string(), "secret": _boolean},
                 required=("target",))(r, kp, value)
    if r.refused_in(kp):
        raise Invalid()
    kinds = [k for k in FILE_KINDS if k in d]
    if len(kinds) != 1:
        raise Invalid("give exactly one source: `template:` (a Jinja2 file), `copy:` (a file copied as is) "
                      "or `var:` (an inventory variable, e.g. calibration in host_vars)")
    kind, source = kinds[0], d[kinds[0]]
    if kind == "var" and not ENV_RE.fullmatch(source):
        raise Invalid(f"{shown(source)} is not an inventory variable name: use {_pattern_hint('env')}", (kind,))
    if kind != "var" and (source.startswith(("/", "~")) or ".." in source.split("/")
                          or not _FILE_SOURCE_RE.fullmatch(source)):
        raise Invalid(f"{shown(source)} must be a path inside the fleet repo, relative to the fleet "
                      "file, without `..` (e.g. params/{{ inventory_hostname }}.yaml)", (kind,))
    if "target" not in d:   # reported as missing (or a key near it suggested)
        raise Invalid()
    target = d["target"]
    # plainly written: its last name is the file's name in the release (`/etc/.` would be `.`)
    if not ABSOLUTE_PATH_RE.fullmatch(target) or target != normal_path(target) or target == "/":
        raise Invalid(f"{shown(target)} must be an absolute file path in the container, written without "
                      "`.`, `..`, `//` or a trailing `/`, e.g. /config/params.yaml", ("target",))
    too_long = path_too_long(target, "/config/params.yaml")
    if too_long:     # its name is a file of the release (store/<digest>/<name>): render would fail to write it
        raise Invalid(too_long, ("target",))
    taken = managed_mount(target)
    if taken:
        raise Invalid(f"{target} is where rosdeploy mounts {taken} itself: choose another path", ("target",))
    in_proc = proc_mount_problem(target)
    if in_proc:
        raise Invalid(in_proc, ("target",))
    return {"kind": kind, "source": source, "target": target, "secret": d.get("secret", False)}


def _check_file_refs(r: Reader, services: dict, files: Any) -> None:
    known = files if isinstance(files, dict) else {}
    declared = r.names(("files",), known) if isinstance(files, dict) else []
    for name in services:
        targets = _file_targets(r, name, known, declared)
        _check_volumes_at_files(r, name, targets)


def _file_targets(r: Reader, service: str, known: dict, declared: list[str]) -> dict[str, str]:
    """The container paths (normalized, as volumes' are) of the files a service mounts -> file name."""
    targets: dict[str, str] = {}
    for i, ref in r.items(("services", service, "files")):
        if ref not in declared:
            from rosdeploy.suggest import did_you_mean
            hint = did_you_mean(ref, declared) or "add it there, or fix the name"
            r.error(("services", service, "files", i), f"no file is named `{ref}` in the top-level `files:`: {hint}")
        elif isinstance(known.get(ref), dict):
            target = normal_path(known[ref]["target"])
            if target in targets:
                r.error(("services", service, "files", i), f"`{ref}` and `{targets[target]}` both mount at {target}")
            targets.setdefault(target, ref)
    for i, ref in r.items(("services", service, "files")):
        target = normal_path(known[ref]["target"]) if isinstance(known.get(ref), dict) else ""
        under = _file_above(target, targets)
        if under:
            r.error(("services", service, "files", i), f"{target} is inside {under}, where files.{targets[under]} "
                                                       "is mounted as a file: the container would not be created "
                                                       "(not a directory); move one of them")
    return targets


def _file_above(path: str, targets: Mapping[str, str]) -> str | None:
    """The file target that `path` lies below (a mount there cannot be made: a file is no folder)."""
    return next((t for t in targets if path.startswith(t + "/")), None)


def _check_volumes_at_files(r: Reader, service: str, targets: dict[str, str]) -> None:
    """A bind mount where one of the service's files is mounted: compose refuses the file ("duplicate
    mount point"), or one of the two would silently hide the other; or below one: no mount can be
    made inside a file."""
    for i, mount in r.items(("services", service, "volumes")):
        target = _mount_target(mount)   # items _mount refused are left out: this one is well formed
        under = _file_above(target, targets)
        if target in targets:
            r.error(("services", service, "volumes", i), f"{target} is also the target of files.{targets[target]}: "
                                                         "one container path takes one mount; change one")
        elif under:
            r.error(("services", service, "volumes", i), f"{target} is inside {under}, where files.{targets[under]} "
                                                         "is mounted as a file: the container would not be created "
                                                         "(not a directory); move one of them")


def problem_at(spec: FleetSpec, keypath: KeyPath, message: str, **kw: Any) -> Problem:
    """A Problem located in the fleet file by key path (for checks that run after loading)."""
    return Doc(spec.path, None, spec.lines).problem(keypath, message, **kw)
