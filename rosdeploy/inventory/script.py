"""Dynamic inventories: an executable `-i` is run with `--list` and read as JSON, as Ansible does.

The script runs without a shell, from its own path, with a time limit, and its
output is data only: the same checks apply to its hosts and vars as to a file's.
Without `_meta.hostvars` in the output, Ansible asks `--host NAME` for each host;
rosdeploy does the same.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

from rosdeploy.errors import Problem
from rosdeploy.inventory.draft import Draft, Origin, make_layer
from rosdeploy.inventory.ranges import valid_name
from rosdeploy.yamlsrc import Doc

TIMEOUT = 60.0   # seconds per run: a cloud API behind the script may be slow, a hung one must not hang us
MAX_OUTPUT = 256 << 20   # bytes: 5,000 robots with rich hostvars print a few MB; a runaway script, without end
POLL = 0.05      # seconds between looks at a running script's time and output size


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

    command = f"`{path.name} {' '.join(args)}`"
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        try:
            # Its own session, so a timeout stops whatever it started too, not only the script.
            proc = subprocess.Popen([str(path.absolute()), *args], stdin=subprocess.DEVNULL, stdout=out,
                                    stderr=err, start_new_session=True)
        except OSError as exc:
            return refuse(f"cannot run it ({exc.strerror}): check its #! line, or remove its execute bit if it "
                          "is not a script")
        stopped = _wait(proc, out.fileno(), err.fileno())
        if stopped == "time":
            return refuse(f"{command} did not finish within {TIMEOUT:g} s: fix the script or export its output "
                          "to a YAML file")
        if stopped == "size":
            return refuse(f"{command} printed more than {MAX_OUTPUT >> 20} MB: a dynamic inventory prints a "
                          "JSON object of groups; fix the script or export its output to a YAML file")
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if proc.returncode != 0:
        tail = stderr.decode("utf-8", "replace").strip()[-300:]
        return refuse(f"{command} exited {proc.returncode}: {tail}")
    try:
        data = json.loads(stdout.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        return refuse(f"{command} did not print JSON ({exc}): a dynamic inventory prints a JSON object of groups")
    if not isinstance(data, dict):
        return refuse("its output must be a JSON object of groups")
    return data


def _wait(proc: subprocess.Popen, *outputs: int) -> str:
    """Wait for the script: "" when it exited, "time" or "size" when it was stopped (with
    everything it started) for running past TIMEOUT or printing more than MAX_OUTPUT. The
    output goes to files, not pipes, so its size is known without reading it."""
    deadline = time.monotonic() + TIMEOUT
    while True:
        try:
            proc.wait(timeout=POLL)
            stopped = ""
        except subprocess.TimeoutExpired:
            stopped = "time" if time.monotonic() > deadline else ""
        if sum(os.fstat(fd).st_size for fd in outputs) > MAX_OUTPUT:
            stopped = "size"
        if stopped or proc.returncode is not None:
            break
    if stopped:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    return stopped
