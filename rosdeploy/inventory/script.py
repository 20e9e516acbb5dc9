"""Dynamic inventories: an executable `-i` is run with `--list` and read as JSON, as Ansible does.

The script runs without a shell, from its own path, with a time limit, and its
output is data only: the same checks apply to its hosts and vars as to a file's.
Without `_meta.hostvars` in the output, Ansible asks `--host NAME` for each host;
rosdeploy does the same.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
from pathlib import Path
from typing import Any

from rosdeploy.errors import Problem
from rosdeploy.inventory.draft import Draft, Origin, make_layer
from rosdeploy.inventory.ranges import valid_name
from rosdeploy.yamlsrc import Doc

TIMEOUT = 60.0   # seconds per run: a cloud API behind the script may be slow, a hung one must not hang us


def is_script(path: Path) -> bool:
    """Executable and starting with `#!`. (Ansible also tries executable files without one and falls
    back to YAML/INI when that fails: files marked executable by a checkout are common.)"""
    if not (path.is_file() and os.access(path, os.X_OK)):
        return False
    try:
        with path.open("rb") as handle:
            return handle.read(2) == b"#!"
    except OSError:
        return False


def parse_script(path: Path, draft: Draft) -> None:
    data = _run(path, ["--list"], draft)
    if data is None:
        return
    origin = Origin(Doc(str(path), data, {(): 1}))
    for group, entry in data.items():
        if group != "_meta":
            _group(origin.child(group), str(group), entry, draft)
    hostvars = data.get("_meta", {}).get("hostvars") if isinstance(data.get("_meta"), dict) else None
    for host in list(draft.hosts) if hostvars is None else []:
        found = _run(path, ["--host", host], draft)
        if found:
            draft.hosts[host].inline.append(make_layer(found, Origin(Doc(str(path), found, {(): 1}))))
    for host, host_vars in (hostvars or {}).items():
        if host in draft.hosts and isinstance(host_vars, dict) and host_vars:
            draft.hosts[host].inline.append(make_layer(host_vars, origin.child("_meta").child("hostvars")
                                                       .child(host)))


def _group(origin: Origin, name: str, entry: Any, draft: Draft) -> None:
    """One group of the JSON, in Ansible's three shapes: a host list, {hosts, vars, children}, or vars."""
    if not valid_name(name, origin, draft, "group"):
        return
    draft.group(name, origin.where)
    if not isinstance(entry, dict):
        entry = {"hosts": entry}
    elif not any(key in entry for key in ("hosts", "vars", "children")):
        entry = {"hosts": [name], "vars": entry}
    hosts, group_vars, children = entry.get("hosts") or [], entry.get("vars") or {}, entry.get("children") or []
    if not isinstance(hosts, list) or not isinstance(group_vars, dict) or not isinstance(children, list):
        draft.problems.append(origin.problem((), "the script's output for this group must be {hosts: [..], "
                                                 "vars: {..}, children: [..]}: fix the script"))
        return
    for host in hosts:
        if valid_name(str(host), origin, draft, "host"):
            draft.add_host(name, str(host), origin, None)
    if group_vars:
        draft.groups[name].inline.append(make_layer(group_vars, origin.child("vars")))
    for child in children:
        if valid_name(str(child), origin, draft, "group"):
            draft.group(str(child), origin.where)
            draft.groups[name].children.setdefault(str(child), origin)


def _run(path: Path, args: list[str], draft: Draft) -> dict[str, Any] | None:
    def refuse(message: str) -> dict[str, Any] | None:
        draft.problems.append(Problem(str(path), None, "", f"dynamic inventory script: {message}"))
        return None

    try:
        # Its own session, so a timeout stops whatever it started too, not only the script.
        proc = subprocess.Popen([str(path.absolute()), *args], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, start_new_session=True)
    except OSError as exc:
        return refuse(f"cannot run it ({exc.strerror}): check its #! line, or remove its execute bit if it is "
                      "not a script")
    with proc:
        try:
            stdout, stderr = proc.communicate(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            return refuse(f"`{path.name} {' '.join(args)}` did not finish within {TIMEOUT:g} s: fix the script "
                          "or export its output to a YAML file")
    if proc.returncode != 0:
        tail = stderr.decode("utf-8", "replace").strip()[-300:]
        return refuse(f"`{path.name} {' '.join(args)}` exited {proc.returncode}: {tail}")
    try:
        data = json.loads(stdout.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        return refuse(f"`{path.name} {' '.join(args)}` did not print JSON ({exc}): a dynamic inventory prints "
                      "a JSON object of groups")
    if not isinstance(data, dict):
        return refuse("its output must be a JSON object of groups")
    return data
