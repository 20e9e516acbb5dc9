"""Checks and converters of the host vars rosdeploy reads (connection, ROS, devices, udev)."""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Callable, Mapping

from rosdeploy import suggest
from rosdeploy.errors import Problem
from rosdeploy.inventory.draft import HostDraft, Layer, Origin, split_where, strings
from rosdeploy.inventory.known import (ALIASES, ANSIBLE_VARS, CONSUMED_VARS, HEX4, MODE, NAME, NEAR_MISS_CUTOFF,
                                       SERIAL, SHELL_UNSAFE, SUBSYSTEM, SYMLINK, TRUE, FALSE, UDEV_KEYS,
                                       UDEV_REQUIRED, UNIX_GROUP, did_you_mean_hint)
from rosdeploy.model import UdevDevice, frozen_map
from rosdeploy.yamlsrc import KeyPath


def check_layer(layer: Layer) -> list[Problem]:
    """Checks that depend on one layer only: done once, not once per host that inherits it."""
    problems: list[Problem] = []
    for key in layer.vars:
        if not isinstance(key, str):
            problems.append(layer.origin.problem((key,), "variable names must be strings: quote it"))
        elif close := _near_miss(key):
            problems.append(layer.origin.problem((key,), f"unknown variable {key!r}: did you mean {close!r}? "
                                                         f"rename it (a free-form variable needs a name not "
                                                         f"this close to one rosdeploy reads)"))
    for keypath, text in strings(layer.vars, ()):
        if "\n" in text or "\0" in text:
            what = "a newline" if "\n" in text else "a NUL byte"
            problems.append(layer.origin.problem(keypath, f"value contains {what}: host vars end up in .env "
                                                          "files and commands, where it would start a new "
                                                          "entry; put multi-line content in a file and give "
                                                          "its path"))
    return problems


def _near_miss(name: str) -> str | None:
    if name in CONSUMED_VARS or name in ANSIBLE_VARS:
        return None
    return suggest.closest(name, CONSUMED_VARS, cutoff=NEAR_MISS_CUTOFF)


class BadValue(Exception):
    """A var's value is wrong; `subpath` points inside it (e.g. ("lidar",) in devices)."""

    def __init__(self, message: str, subpath: KeyPath = ()) -> None:
        super().__init__(message)
        self.message = message
        self.subpath = subpath


def host_fields(host: HostDraft, merged: Mapping[str, Any], origins: Mapping[str, Origin],
                 base: Path) -> tuple[dict[str, Any], list[Problem]]:
    converters: dict[str, tuple[str, Callable[[Any], Any]]] = {
        "ansible_host": ("address", _to_address),
        "ansible_port": ("port", _to_port),
        "ansible_user": ("user", _to_user),
        "ansible_ssh_private_key_file": ("key_file", lambda v: _to_key_file(v, base)),
        "ros_domain_id": ("ros_domain_id", _to_domain_id),
        "devices": ("devices", _to_devices),
        "gpu": ("gpu", _to_bool),
        "udev": ("udev", _to_udev),
        "ros_network": ("network", _to_network),
    }
    fields: dict[str, Any] = {"address": host.name}
    problems: list[Problem] = []
    for var, (name, convert) in converters.items():
        used = var if var in merged else next((a for a, p in ALIASES.items() if p == var and a in merged), None)
        if used is None:
            continue
        try:
            fields[name] = convert(merged[used])
        except BadValue as bad:
            problems.append(origins[used].problem((used, *bad.subpath), bad.message))
    if "ros_domain_id" not in merged:
        problems.append(_missing_domain_id(host))
    return fields, problems


def _missing_domain_id(host: HostDraft) -> Problem:
    path, line = split_where(host.source)
    return Problem(path, line, f"{host.name}.ros_domain_id",
                   f"robot {host.name!r} has no ros_domain_id: add `ros_domain_id: N` (0-232) to "
                   f"host_vars/{host.name}.yml, to its entry here, or to its group's vars (robots on "
                   "one ros_network need distinct IDs)")


def to_int(value: Any, what: str) -> int:
    # Ansible accepts "2222" where it wants a number; so do we, but nothing looser.
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().isdigit():
        return int(value)
    raise BadValue(f"must be {what}, got {value!r}")


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


def _to_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return value
    # Ansible's boolean(): INI writes `gpu=true` as a string.
    if isinstance(value, str) and value.strip().lower() in TRUE + FALSE:
        return value.strip().lower() in TRUE
    raise BadValue(f"must be true or false, got {value!r}")


def _safe_text(value: Any, what: str, extra_unsafe: str = "") -> str:
    if not isinstance(value, str) or not value:
        raise BadValue(f"must be {what} (a non-empty string), got {value!r}")
    bad = sorted(set(value) & (SHELL_UNSAFE | set(extra_unsafe)))
    if bad:
        shown = ", ".join(repr(c) for c in bad)
        raise BadValue(f"{what} {value!r} contains {shown}: whitespace and shell metacharacters are not "
                       "allowed here; fix the value")
    return value


def _to_address(value: Any) -> str:
    address = _safe_text(value, "a host name or IP address")
    if address.startswith("-"):
        raise BadValue(f"{address!r} starts with '-', which ssh would read as an option; fix the address")
    return address


def _to_user(value: Any) -> str:
    user = _safe_text(value, "a user name")
    if user.startswith("-"):
        raise BadValue(f"{user!r} starts with '-', which ssh would read as an option; fix the user name")
    return user


def _to_key_file(value: Any, base: Path) -> str:
    if not isinstance(value, str) or not value:
        raise BadValue(f"must be a path to a private key file, got {value!r}")
    path = os.path.expanduser(value)
    if not os.path.isabs(path):  # relative to the inventory, not to wherever rosdeploy runs
        path = os.path.normpath(os.path.join(os.path.abspath(base), path))
    return _safe_text(path, "a key file path")


def _to_network(value: Any) -> str:
    if isinstance(value, str) and NAME.fullmatch(value):
        return value
    raise BadValue(f"must be a network name (letters, digits, '_', '-', '.'), got {value!r}")


def _to_devices(value: Any) -> Mapping[str, str]:
    if not isinstance(value, Mapping):
        raise BadValue("must be a mapping of logical name to device path, e.g. "
                       "{lidar: /dev/robot/lidar}")
    out: dict[str, str] = {}
    for name, path in value.items():
        if not isinstance(name, str) or not NAME.fullmatch(name):
            raise BadValue(f"invalid device name {name!r}: use letters, digits, '_', '-', '.'", (name,))
        out[name] = _device_path(path, (name,))
    return frozen_map(out)


def _device_path(path: Any, subpath: KeyPath) -> str:
    try:
        # ':' and ',' separate fields in compose's `devices:` entries.
        text = _safe_text(path, "an absolute device path", extra_unsafe=":,")
    except BadValue as bad:
        raise BadValue(bad.message, subpath) from None
    if not text.startswith("/") or "/../" in text + "/":
        raise BadValue(f"must be an absolute device path on the robot (e.g. /dev/robot/lidar), got {text!r}",
                       subpath)
    return text


def _to_udev(value: Any) -> tuple[UdevDevice, ...]:
    if not isinstance(value, list):
        raise BadValue("must be a list of devices, each {symlink, subsystem, vendor, product}")
    devices = tuple(_udev_device(entry, index) for index, entry in enumerate(value))
    seen: set[str] = set()
    for index, device in enumerate(devices):
        if device.symlink in seen:
            raise BadValue(f"symlink {device.symlink!r} is listed twice: keep one entry", (index, "symlink"))
        seen.add(device.symlink)
    return devices


def _udev_device(entry: Any, index: int) -> UdevDevice:
    if not isinstance(entry, Mapping):
        raise BadValue("each udev entry must be a mapping with symlink, subsystem, vendor, product", (index,))
    for key in entry:
        if key not in UDEV_KEYS:
            raise BadValue(f"unknown key {key!r}{did_you_mean_hint(key, UDEV_KEYS)} "
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
        serial=_udev_optional(entry, "serial", SERIAL, "a serial number (letters, digits, _.:/+-)", index),
        group=_udev_optional(entry, "group", UNIX_GROUP, "a Unix group name like dialout", index),
        mode=_udev_mode(entry.get("mode", "0660"), (index, "mode")),
    )


def _udev_text(value: Any, pattern: re.Pattern[str], what: str, subpath: KeyPath) -> str:
    if isinstance(value, str) and pattern.fullmatch(value):
        return value
    quote = " (quote it: YAML reads unquoted digits as a number)" if isinstance(value, int) else ""
    raise BadValue(f"must be {what}, got {value!r}{quote}", subpath)


def _udev_optional(entry: Mapping[str, Any], key: str, pattern: re.Pattern[str], what: str,
                   index: int) -> str | None:
    value = entry.get(key)
    return None if value is None else _udev_text(value, pattern, what, (index, key))


def _udev_hex(value: Any, subpath: KeyPath) -> str:
    return _udev_text(value, HEX4, "4 hex digits as a string, e.g. \"0403\"", subpath).lower()


def _udev_symlink(value: Any, subpath: KeyPath) -> str:
    if isinstance(value, str) and value.startswith("/dev/"):
        raise BadValue(f"write the symlink relative to /dev: {value[5:]!r}", subpath)
    link = _udev_text(value, SYMLINK, "a path relative to /dev, e.g. robot/lidar", subpath)
    if ".." in link.split("/"):
        raise BadValue(f"must stay inside /dev, got {link!r}", subpath)
    return link


def _udev_mode(value: Any, subpath: KeyPath) -> str:
    mode = _udev_text(value, MODE, "an octal mode as a string, e.g. \"0660\"", subpath)
    return mode.zfill(4)

