"""Checks and converters of the host vars rosdeploy reads (connection, ROS, devices, udev)."""
from __future__ import annotations

import functools
import os
import re
import stat
import unicodedata
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

from rosdeploy import suggest
from rosdeploy.errors import Problem, shown
from rosdeploy.fleet import (REMOTE_PATH_RE, deploy_root_problem, home_problem, is_ip_address, known_hosts_problem,
                             path_too_long)
from rosdeploy.inventory.draft import Layer, Origin
from rosdeploy.inventory.known import (ANSIBLE_VARS, FALSE, HEX4, MODE, NAME, NEAR_MISS_CUTOFF, SERIAL,
                                       SHELL_UNSAFE, SUBSYSTEM, SYMLINK, TRUE, UDEV_KEYS, UDEV_REQUIRED,
                                       UNIX_GROUP, did_you_mean_hint)
from rosdeploy.model import UdevDevice, frozen_map
from rosdeploy.ready import GATE_VARS, checked_var, is_gate_shaped
from rosdeploy.yamlsrc import KeyPath


@dataclass(frozen=True)
class Var:
    """One var rosdeploy reads: the Host field it fills, its converter, and whose name it is.

    `shape` is set for short names other tools use too (`devices`, `gpu`): a value that
    fails it belongs to someone else, so it is a warning and ignored, not a refusal.
    Through the `rosdeploy_` name the value is always rosdeploy's, and checked strictly.
    """

    field: str | None            # None: the var stays in Host.vars (normalised), read by deploy/transport
    convert: Callable[[Any], Any]
    shape: Callable[[Any], bool] | None = None
    what: str = ""               # the expected shape, for the warning


def host_fields(name: str, read: Callable[[str], Any], origins: Mapping[str, Origin],
                secret_source: Callable[[str], str | None] = lambda var: None,
                ) -> tuple[dict[str, Any], dict[str, Any], list[Problem], list[Problem]]:
    """(Host fields, normalised vars, errors, warnings) of one host; `read` templates a var;
    `secret_source`: the vault var a var's value came from, once read (see _refused)."""
    fields: dict[str, Any] = {"address": name}
    normalised: dict[str, Any] = {}
    errors: list[Problem] = []
    warnings: list[Problem] = []

    def take(var: str, spec: Var, foreign_ok: bool) -> None:
        try:
            value = read(var)
            if value is None:      # `ansible_user:` with nothing: unset, as in Ansible
                return
            if foreign_ok and spec.shape is not None and not spec.shape(value):
                warnings.append(_foreign(name, var, value, spec, origins[var]))
                return
            converted = spec.convert(value)
        except BadValue as bad:
            errors.append(origins[var].problem((var, *bad.subpath), _refused(name, var, bad, secret_source(var))))
            return
        if spec.field is None:
            normalised[var] = converted
        else:
            fields[spec.field] = converted

    for field, candidates in CONNECTION.items():
        # Ansible's ssh plugin: of the names it lists, the last one set wins (ansible_ssh_host
        # beats ansible_host), whichever inventory level each came from.
        used = next((var for var in reversed(candidates) if var in origins), None)
        if used is not None:
            take(used, Var(field, CONVERTERS[field]), False)
            if field == "key_file":
                where = origins[used].problem((used,), "")
                fields["key_file_var"] = f"{used} ({where.file}:{where.line})" if where.line else used
    for short, spec in OWN_VARS.items():
        prefixed = PREFIX + short
        if prefixed in origins:
            take(prefixed, spec, False)
        elif short in origins:
            take(short, spec, True)
    for var, spec in (*PREFIXED_ONLY.items(), *ANSIBLE_READ.items()):
        if var in origins:
            take(var, spec, False)
    return fields, normalised, errors, warnings


def _foreign(host: str, var: str, value: Any, spec: Var, origin: Origin) -> Problem:
    return origin.problem((var,), f"robot {shown(host)}: {var} is {shown(value, 60)}, not rosdeploy's {spec.what}: "
                                  f"another tool's variable, ignored by rosdeploy; give rosdeploy its own as "
                                  f"{PREFIX}{var}",
                          severity="warning")


def case_variant(names: Iterable[Any], var: str) -> str | None:
    """A name in `names` that is `var` in another case (`ROS_DOMAIN_ID` for ros_domain_id), or None:
    for an error about a missing var, which is likely there, misspelt."""
    return next((name for name in names if isinstance(name, str) and name != var and name.lower() == var), None)


def check_layer(layer: Layer) -> tuple[list[Problem], list[Problem]]:
    """(errors, warnings) that depend on one layer only: found once, not once per host."""
    errors: list[Problem] = []
    warnings: list[Problem] = []
    for key in layer.vars:
        if not isinstance(key, str):
            errors.append(layer.origin.problem((key,), "variable names must be strings: quote it"))
        elif key.startswith(PREFIX) and key not in PREFIXED_VARS:
            hint = suggest.did_you_mean(key, PREFIXED_VARS) or f"known: {', '.join(sorted(PREFIXED_VARS))}"
            errors.append(layer.origin.problem((key,), f"unknown rosdeploy variable {shown(key)}: {hint} "
                                                       "(the rosdeploy_ prefix is rosdeploy's own)"))
        elif key.lower().startswith(PREFIX) and not key.startswith(PREFIX):
            # Variable names are case-sensitive: `ROSDEPLOY_DEVICES` is not rosdeploy's, and would be
            # ignored without a word (the `rosdeploy_` check above and _near_miss's cutoff both miss it).
            hint = suggest.did_you_mean(key.lower(), PREFIXED_VARS) or f"known: {', '.join(sorted(PREFIXED_VARS))}"
            warnings.append(layer.origin.problem((key,), f"{shown(key)} is not a variable rosdeploy reads (names are "
                                                         f"case-sensitive, rosdeploy's are lower-case): {hint}",
                                                 severity="warning"))
        elif key in _NOT_HONOURED and _not_honoured(key, layer.vars[key]):
            warnings.append(layer.origin.problem((key,), _not_honoured(key, layer.vars[key]), severity="warning"))
        elif close := _near_miss(key):
            warnings.append(layer.origin.problem((key,), f"{shown(key)} is not a variable rosdeploy reads: did you "
                                                         f"mean {shown(close)}? (ignored if it is another tool's)",
                                                 severity="warning"))
    return errors, warnings


# Ansible's ways to reach a host that rosdeploy does not take: it connects over SSH, with its own
# client, its host key checks always on.
_NOT_HONOURED = ("ansible_connection", "ansible_ssh_common_args", "ansible_ssh_extra_args", "ansible_password",
                 "ansible_ssh_pass", "ansible_ssh_password", "ansible_ssh_executable", "ansible_become_exe",
                 "ansible_become_flags", "ansible_host_key_checking", "ansible_ssh_host_key_checking")
_PASSWORDS = ("ansible_password", "ansible_ssh_pass", "ansible_ssh_password")
_HOST_KEY_CHECKING = ("ansible_host_key_checking", "ansible_ssh_host_key_checking")
_SSH_CONNECTIONS = ("ssh", "smart", "paramiko", "paramiko_ssh")


def connection_ignored(value: Any) -> str:
    """The warning for an `ansible_connection` other than SSH, or "" (a template is judged by its
    value, per robot: merge._templated_connection)."""
    if not isinstance(value, str) or value in _SSH_CONNECTIONS or "{{" in value:
        return ""
    return f"{shown(value)} is ignored: rosdeploy reaches every robot over SSH (with sshd at ansible_host)"


def _not_honoured(key: str, value: Any) -> str:
    """The warning for an Ansible connection var rosdeploy ignores, or "" when it changes nothing."""
    if key == "ansible_connection":
        return connection_ignored(value)
    if key in _PASSWORDS:
        return ("ignored: rosdeploy logs in with SSH keys only (ansible_ssh_private_key_file, the ssh agent or "
                "the ssh config's IdentityFile); a robot that takes only a password is refused at connect")
    if key in _HOST_KEY_CHECKING:
        return ("" if value in (True, "true", "True", "yes", 1) else
                "ignored: rosdeploy always checks host keys; add the robot's key to known_hosts "
                "(ssh-keyscan, after checking its fingerprint)")
    if key in ("ansible_become_exe", "ansible_become_flags"):
        return "ignored: rosdeploy becomes root with sudo alone (`sudo -S`, or `sudo -n` with no password)"
    if key == "ansible_ssh_executable":
        return "ignored: rosdeploy runs no ssh command (it connects with its own SSH client)"
    return ("ignored: rosdeploy runs no ssh command and always checks host keys; put SSH options "
            "(ProxyJump, Port, User) in an OpenSSH config, the fleet file's `ssh.config` (default ~/.ssh/config)")


def _refused(name: str, var: str, bad: BadValue, source: str | None) -> str:
    """Why a var's value was refused. A value from a vault is never quoted, in any form: masking the
    secret's text misses a transformed one (`{{ token | list }}` quoted one character at a time)."""
    if source is None:
        return f"robot {shown(name)}: {bad.message}"
    # "must be X, got Y": X is the rule, with no part of the value in it
    must = (re.split(r"[,;] got ", bad.message)[0] if bad.message.startswith("must be ") else
            "is not valid here")
    return (f"robot {shown(name)}: {var}, computed from vault var {shown(source)}, {must}; got '********' (a "
            "secret is never shown: check it with `rosdeploy vault view`)")


@functools.lru_cache(maxsize=4096)     # 5,000 host_vars files hold the same few keys
def _near_miss(name: str) -> str | None:
    if name in CONSUMED_VARS or name in ANSIBLE_VARS:
        return None
    # `ROS_DOMAIN_ID` (the environment variable's spelling), `GPU`: difflib's ratio is low for
    # another case, so a dict lookup finds them
    same = _BY_LOWER.get(name.lower())
    if same is not None:
        return same
    near = _of_length(len(name))
    return suggest.closest(name, near, cutoff=NEAR_MISS_CUTOFF) if near else None


@functools.cache
def _of_length(length: int) -> tuple[str, ...]:
    """The names a word of `length` characters can be near: difflib's ratio is at most
    2*min(a, b)/(a + b), so the others never pass the cutoff. Skipping them in Python, rather
    than in difflib's per-name loop, makes a vars file of 250,000 keys 10 times quicker."""
    return tuple(var for var in CONSUMED_VARS if 2 * min(length, len(var)) >= NEAR_MISS_CUTOFF * (length + len(var)))


class BadValue(Exception):
    """A var's value is wrong; `subpath` points inside it (e.g. ("lidar",) in devices)."""

    def __init__(self, message: str, subpath: KeyPath = ()) -> None:
        super().__init__(message)
        self.message = message
        self.subpath = subpath


def to_int(value: Any, what: str) -> int:
    # Ansible accepts "2222" where it wants a number; so do we, but nothing looser: ASCII
    # digits only ("²".isdigit() is True, and int("²") raises).
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, str) and _ASCII_INT.fullmatch(value.strip()):
        if len(value.strip()) > 100:   # int() of 4,300 digits raises; no setting takes 100
            raise BadValue(f"must be {what}, got a number of {len(value.strip())} digits")
        return int(value)
    raise BadValue(f"must be {what}, got {shown(value)}")


def _to_port(value: Any) -> int:
    port = to_int(value, "a port number (an integer 1-65535)")
    if not 1 <= port <= 65535:
        raise BadValue(f"must be a port number 1-65535, got {port}")
    return port


def _to_domain_id(value: Any) -> int:
    domain = to_int(value, "an integer 0-232 (the ROS_DOMAIN_ID)")
    if not 0 <= domain <= 232:
        raise BadValue(f"must be 0-232 (DDS maps higher IDs to ports outside the valid range), got {domain}")
    return domain


def _to_rate(value: Any) -> Any:
    """Checked at load, as the fleet file's images.max_rate is; read again where images move."""
    from rosdeploy.images.refs import parse_rate
    try:
        parse_rate(value)
    except ValueError as exc:
        why = "bits per second; write bytes, " if "bits" in str(exc) else ""
        raise BadValue(f"must be a rate in bytes per second from 1kB/s up ({why}e.g. 2MB/s or 500kB/s), "
                       f"got {shown(value)}") from None
    return value


def ansible_bool(value: Any) -> bool:
    """A boolean as Ansible's boolean() reads it; BadValue when it is neither true nor false."""
    if isinstance(value, bool):
        return value
    # Ansible's boolean(): INI writes `gpu=true` as a string, and the numbers 1 and 0 are true and false
    if isinstance(value, str) and value.strip().lower() in TRUE + FALSE:
        return value.strip().lower() in TRUE
    if _is_number_bool(value):
        return bool(value)
    raise BadValue(f"must be true or false, got {shown(value)}")


def _is_number_bool(value: Any) -> bool:
    """1 and 0 (1.0, 0.0), which Ansible's boolean() reads as true and false, as it does "1" and "0"."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value in (0, 1)


def _safe_text(value: Any, what: str, extra_unsafe: str = "") -> str:
    if not isinstance(value, str) or not value:
        raise BadValue(f"must be {what} (a non-empty string), got {shown(value)}")
    # also any other whitespace or unprintable character (U+2028, U+0085, ESC; str.isprintable()
    # is false for every separator but the ASCII space): ssh's resolver and the files rendered
    # from the value (logrotate's paths) would read them as separators
    bad = sorted(set(value) & (SHELL_UNSAFE | set(extra_unsafe)) |
                 (set() if value.isprintable() else {c for c in value if not c.isprintable()}))
    if bad:
        chars = ", ".join(repr(c) for c in bad)
        raise BadValue(f"{what} {shown(value)} contains {chars}: whitespace and shell metacharacters are not "
                       "allowed here; fix the value")
    return value


MAX_HOST_NAME = 253     # DNS's limit on a whole name (RFC 1035), and well past any ssh config alias


def _to_address(value: Any) -> str:
    """A host name, an ssh config alias or an IP address: ssh is given it as its destination."""
    address = _safe_text(value, "a host name or IP address")
    if address.startswith("-"):
        raise BadValue(f"{shown(address)} starts with '-', which ssh would read as an option; fix the address")
    if len(address) > MAX_HOST_NAME:
        raise BadValue(f"{shown(address)} is longer than a host name can be ({MAX_HOST_NAME} characters): give "
                       "the robot's host name or IP address")
    problem = _not_an_address(address) or _no_host_name_characters(address) or _not_a_host_name(address)
    if problem:
        raise BadValue(f"{shown(address)} {problem}")
    return address


def _no_host_name_characters(address: str) -> str | None:
    """Why a name holds characters no resolver takes (`a,b`, `a%b`, `a=b`, Arabic-Indic digits), or None.
    The idna codec passes them; a known_hosts line reads `a,b` as two names. An IP address (with
    an IPv6 `%zone`) is checked by is_ip_address; non-ASCII letters are IDNA names (bücher.example)."""
    if is_ip_address(address):
        return None
    bad = sorted({c for c in address if not _host_name_character(c)})
    if not bad:
        return None
    return (f"holds {', '.join(repr(c) for c in bad)}: a host name or ssh config alias has letters, digits, "
            "'-', '_' and '.' only (digits in ASCII, '%' only in an IPv6 zone: fe80::1%eth0); "
            "give the robot's host name or IP address")


def _host_name_character(c: str) -> bool:
    if c.isascii():
        return c.isalnum() or c in "-_."
    # IDNA labels hold letters and combining marks; a non-ASCII digit is no digit to a resolver
    return unicodedata.category(c)[0] in "LM"


def _not_a_host_name(address: str) -> str | None:
    """Why a name the resolver would refuse (an empty label, one over 63 characters) is no host name.
    It passed validate and stopped `status` with an internal UnicodeError from the idna codec."""
    if is_ip_address(address):
        return None
    try:
        address.encode("idna")
    except UnicodeError:
        return ("is not a valid host name (a dot-separated label is empty or longer than 63 characters): "
                "give the robot's host name or IP address")
    return None


def _not_an_address(address: str) -> str | None:
    """What a URL, user@host or host:port given as an address is, and where its parts go; or None."""
    if "/" in address:
        return "is a URL or a path, not an address: give the host name or IP address alone (the port in ansible_port)"
    if "@" in address:
        return "holds a user (user@host): give the host alone, and the user in ansible_user"
    if ":" in address and not is_ip_address(address):
        return "is not an IPv6 address, and a port goes in ansible_port: give the host name or IP address alone"
    return None


MAX_USER = 256    # far past Linux's 32 (useradd) and a directory service's names; a bound for the paths built from it


def _to_user(value: Any) -> str:
    user = _safe_text(value, "a user name")
    if user.startswith("-"):
        raise BadValue(f"{shown(user)} starts with '-', which ssh would read as an option; fix the user name")
    if len(user) > MAX_USER:
        raise BadValue(f"{shown(user)} is longer than a user name can be ({MAX_USER} characters); fix the user name")
    if "/" in user or user in (".", ".."):
        # no Linux user has such a name, and the home rosdeploy derives from it (/home/<user>, for
        # logrotate) would be another folder: /home/../etc
        raise BadValue(f"{shown(user)} is no user name: a user name holds no '/' and is not '.' or '..'; "
                       "fix the user name")
    return user


def _to_local_path(value: Any) -> str:
    """A file on this machine: `~` expanded, a relative path taken from the working directory,
    as Ansible (ssh) does for ansible_ssh_private_key_file; `{{ inventory_dir }}/...` for a
    path beside the inventory."""
    if not isinstance(value, str) or not value:
        raise BadValue(f"must be a path to a file, got {shown(value)}")
    return _safe_text(os.path.abspath(os.path.expanduser(value)), "a file path")


def _to_key_file(value: Any) -> str:
    """A private key file on this machine. One that exists but is no regular file (a folder, a
    fifo, a device) is refused here, where validate sees it; a missing one is the connection's
    error (it may be made before apply). The file itself is read only when connecting."""
    path = _to_local_path(value)
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return path
    if not stat.S_ISREG(mode):
        raise BadValue(f"{shown(path)} is {'a folder' if stat.S_ISDIR(mode) else 'not a regular file'}, not a "
                       "private key file: give the key's path")
    return path


def _to_known_hosts(value: Any) -> str:
    """A known_hosts path, refused at load when it cannot be one (fleet.known_hosts_problem)."""
    path = _to_local_path(value)
    problem = known_hosts_problem(path)
    if problem:
        raise BadValue(problem)
    return path


def _to_remote_root(value: Any) -> str:
    """A directory on the robot, the way the fleet file's deploy_root is checked."""
    # The pattern admits letters, digits and `_.-` only: no shell metacharacter gets through.
    if not isinstance(value, str) or not REMOTE_PATH_RE.fullmatch(value) or ".." in value.split("/"):
        raise BadValue(f"must be an absolute path or one under ~ on the robot, without '..' or shell "
                       f"metacharacters (e.g. /opt/rosdeploy or ~/rosdeploy), got {shown(value)}")
    problem = deploy_root_problem(value)     # the root, /proc, /sys, /dev, too long: as deploy_root
    if problem:
        raise BadValue(problem)
    return value


def _to_home(value: Any) -> str:
    problem = home_problem(value)
    if problem:
        raise BadValue(problem)
    return str(value)


def _to_route(value: Any) -> str:
    if value in IMAGE_ROUTES:
        return str(value)
    raise BadValue(f"must be one of {', '.join(IMAGE_ROUTES)}, got {shown(value)}"
                   f"{did_you_mean_hint(value, IMAGE_ROUTES)}")


def _to_compose(value: Any) -> str:
    if value in COMPOSE_CHOICES:
        return str(value)
    raise BadValue(f"must be one of {', '.join(COMPOSE_CHOICES)}, got {shown(value)}"
                   f"{did_you_mean_hint(value, COMPOSE_CHOICES)}")


def _to_network(value: Any) -> str:
    if isinstance(value, str) and NAME.fullmatch(value):
        return value
    raise BadValue(f"must be a network name (letters, digits, '_', '-', '.'), got {shown(value)}")


def _to_devices(value: Any) -> Mapping[str, str]:
    if not isinstance(value, Mapping):
        raise BadValue("must be a mapping of logical name to device path, e.g. "
                       "{lidar: /dev/robot/lidar}")
    out: dict[str, str] = {}
    for name, path in value.items():
        if not isinstance(name, str) or not NAME.fullmatch(name):
            raise BadValue(f"invalid device name {shown(name)}: use letters, digits, '_', '-', '.'", (name,))
        out[name] = _device_path(path, (name,))
    return frozen_map(out)


def _device_path(path: Any, subpath: KeyPath) -> str:
    try:
        # ':' and ',' separate fields in compose's `devices:` entries.
        text = _safe_text(path, "an absolute device path", extra_unsafe=":,")
    except BadValue as bad:
        raise BadValue(bad.message, subpath) from None
    # Written as the kernel reads it (`/dev//x`, `/dev/./x/` are /dev/x): Docker maps every device
    # under a folder given as a device, so `/dev//` was all of the robot's devices.
    parts = [part for part in text.split("/") if part not in ("", ".")]
    if ".." in parts:
        raise BadValue(f"{shown(text)} holds `..`: write the device's own path under /dev "
                       "(e.g. /dev/robot/lidar)", subpath)
    if not text.startswith("/") or parts[:1] != ["dev"] or len(parts) < 2:
        raise BadValue(f"must be a device path under /dev on the robot (e.g. /dev/robot/lidar), not /dev itself, "
                       f"got {shown(text)}", subpath)
    path = "/" + "/".join(parts)
    _within_path_limits(path, "/dev/robot/lidar", subpath)
    return path


def _within_path_limits(path: str, example: str, subpath: KeyPath) -> None:
    """Refuse a path Linux cannot take, in the words of the fleet file's files.target bound."""
    too_long = path_too_long(path, example)
    if too_long:
        raise BadValue(too_long, subpath)


def _to_udev(value: Any) -> tuple[UdevDevice, ...]:
    if not isinstance(value, list):
        raise BadValue("must be a list of devices, each {symlink, subsystem, vendor, product}")
    devices = tuple(_udev_device(entry, index) for index, entry in enumerate(value))
    seen: set[str] = set()
    for index, device in enumerate(devices):
        if device.symlink in seen:
            raise BadValue(f"symlink {shown(device.symlink)} is listed twice: keep one entry", (index, "symlink"))
        seen.add(device.symlink)
    return devices


def _udev_device(entry: Any, index: int) -> UdevDevice:
    if not isinstance(entry, Mapping):
        raise BadValue("each udev entry must be a mapping with symlink, subsystem, vendor, product", (index,))
    for key in entry:
        if key not in UDEV_KEYS:
            raise BadValue(f"unknown key {shown(key)}{did_you_mean_hint(key, UDEV_KEYS)} "
                           f"(known: {', '.join(UDEV_KEYS)})", (index, key))
    for key in UDEV_REQUIRED:
        if key not in entry:
            raise BadValue(f"missing {key}: every udev entry needs {', '.join(UDEV_REQUIRED)}", (index,))
    return UdevDevice(
        symlink=_udev_symlink(entry["symlink"], (index, "symlink")),
        subsystem=_udev_text(entry["subsystem"], SUBSYSTEM, "a subsystem like tty or video4linux",
                             (index, "subsystem")),
        vendor=_udev_hex(entry["vendor"], (index, "vendor")),
        product=_udev_hex(entry["product"], (index, "product")),
        serial=_udev_serial(entry, index),
        group=_udev_optional(entry, "group", UNIX_GROUP, "a Unix group name like dialout", index),
        mode=_udev_mode(entry.get("mode", "0660"), (index, "mode")),
    )


def _udev_text(value: Any, pattern: re.Pattern[str], what: str, subpath: KeyPath) -> str:
    if isinstance(value, str) and pattern.fullmatch(value):
        return value
    quote = " (quote it: YAML reads unquoted digits as a number)" if isinstance(value, int) else ""
    raise BadValue(f"must be {what}, got {shown(value)}{quote}", subpath)


def _udev_optional(entry: Mapping[str, Any], key: str, pattern: re.Pattern[str], what: str,
                   index: int) -> str | None:
    value = entry.get(key)
    return None if value is None else _udev_text(value, pattern, what, (index, key))


# A USB serial is at most 126 characters (its string descriptor is 255 bytes); 255 leaves room for other buses'.
MAX_SERIAL = 255


def _udev_serial(entry: Mapping[str, Any], index: int) -> str | None:
    serial = _udev_optional(entry, "serial", SERIAL, "a serial number (letters, digits, _.:/+-)", index)
    if serial is not None and len(serial) > MAX_SERIAL:
        # no device reports it, so the rule would never match: the symlink would never appear
        raise BadValue(f"a serial of {len(serial)} characters: no device reports one over {MAX_SERIAL} (a USB "
                       "serial has at most 126); copy it from `udevadm info --attribute-walk`", (index, "serial"))
    return serial


def _udev_hex(value: Any, subpath: KeyPath) -> str:
    return _udev_text(value, HEX4, "4 hex digits as a string, e.g. \"0403\"", subpath).lower()


def _udev_symlink(value: Any, subpath: KeyPath) -> str:
    if isinstance(value, str) and value.startswith("/dev/"):
        raise BadValue(f"write the symlink relative to /dev: {shown(value[5:])}", subpath)
    link = _udev_text(value, SYMLINK, "a path relative to /dev, e.g. robot/lidar", subpath)
    if ".." in link.split("/"):
        raise BadValue(f"must stay inside /dev, got {shown(link)}", subpath)
    _within_path_limits("/dev/" + link, "robot/lidar", subpath)
    return link


def _udev_mode(value: Any, subpath: KeyPath) -> str:
    mode = _udev_text(value, MODE, "an octal mode as a string, e.g. \"0660\"", subpath)
    return mode.zfill(4)


def _is_bool(value: Any) -> bool:
    return isinstance(value, bool) or (isinstance(value, str) and value.strip().lower() in TRUE + FALSE) or \
        _is_number_bool(value)


def _is_udev(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(e, Mapping) and "symlink" in e for e in value)


PREFIX = "rosdeploy_"
COMPOSE_CHOICES = ("auto", "v1", "v2")
IMAGE_ROUTES = ("registry", "ssh")
_ASCII_INT = re.compile(r"[0-9]+")

CONVERTERS: dict[str, Callable[[Any], Any]] = {
    "address": _to_address, "port": _to_port, "user": _to_user, "key_file": _to_key_file}
# Host field -> the names Ansible's ssh plugin reads for it, lowest precedence first.
CONNECTION: dict[str, tuple[str, ...]] = {
    "address": ("ansible_host", "ansible_ssh_host"),
    "port": ("ansible_port", "ansible_ssh_port"),
    "user": ("ansible_user", "ansible_ssh_user"),
    "key_file": ("ansible_private_key_file", "ansible_ssh_private_key_file"),
}
# rosdeploy's own vars: `rosdeploy_NAME` always; the short NAME too, unless another tool's value sits there.
OWN_VARS: dict[str, Var] = {
    "ros_domain_id": Var("ros_domain_id", _to_domain_id),   # no other tool's name: always checked
    "ros_network": Var("network", _to_network, lambda v: isinstance(v, str), "network name (a string)"),
    "devices": Var("devices", _to_devices, lambda v: isinstance(v, Mapping),
                   "devices map (logical name: /dev/... path)"),
    "gpu": Var("gpu", ansible_bool, _is_bool, "gpu flag (true or false)"),
    "udev": Var("udev", _to_udev, _is_udev, "udev list (entries with symlink, subsystem, vendor, product)"),
    **{name: Var(None, checked_var(name), is_gate_shaped, what)   # ready, window
       for name, what in GATE_VARS.items()},
}
# Read from Host.vars by transport, deploy and render; checked (and paths made absolute) here.
PREFIXED_ONLY: dict[str, Var] = {
    "rosdeploy_known_hosts": Var(None, _to_known_hosts),
    "rosdeploy_deploy_root": Var(None, _to_remote_root),
    "rosdeploy_home": Var(None, _to_home),
    "rosdeploy_compose": Var(None, _to_compose),
    "rosdeploy_images_via": Var(None, _to_route),          # docs/images.md
    "rosdeploy_images_max_rate": Var(None, _to_rate),
}
# Ansible's own vars rosdeploy reads (hostchanges.become), checked and made a bool here: a
# string reader elsewhere took `off`, `n`, `f` and 0.0 for true, and would have used sudo.
ANSIBLE_READ: dict[str, Var] = {"ansible_become": Var(None, ansible_bool)}
PREFIXED_VARS = frozenset({*(PREFIX + name for name in OWN_VARS), *PREFIXED_ONLY})
CONSUMED_VARS = (*OWN_VARS, *PREFIXED_VARS, *(var for names in CONNECTION.values() for var in names))
_BY_LOWER = {var.lower(): var for var in CONSUMED_VARS}
