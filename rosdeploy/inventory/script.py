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
from rosdeploy.inventory import ranges
from rosdeploy.inventory.draft import Draft, Origin, make_layer
from rosdeploy.inventory.ranges import valid_name
from rosdeploy.yamlsrc import MAX_DEPTH, Doc, KeyPath, dotted, not_text

TIMEOUT = 60.0   # seconds per run: a cloud API behind the script may be slow, a hung one must not hang us
MAX_OUTPUT = 64 << 20    # bytes: 5,000 robots with rich hostvars print a few MB; a runaway script, without end
MAX_STDERR = 2000        # characters of a failed script's stderr quoted in the error (its end)
PRIVATE_ENV = ("ROSDEPLOY_VAULT_PASSWORD", "ROSDEPLOY_VAULT_PASSWORD_FILE")   # never passed to a script
POLL = 0.05      # seconds between looks at a running script's time and output size


def is_script(path: Path) -> bool:
    """Executable and starting with `#!`. (Ansible also tries executable files without one and falls
    back to YAML/INI when that fails: files marked executable by a checkout are common.)"""
    try:   # is_file() raises on EACCES (Python 3.11): a file under /proc, or another user's
        if not (path.is_file() and os.access(path, os.X_OK)):
            return False
        with path.open("rb") as handle:
            return handle.read(2) == b"#!"
    except OSError:
        return False


def parse_script(path: Path, draft: Draft) -> None:
    data = _run(path, ["--list"], draft)
    if data is None:
        return
    origin = Origin(Doc(str(path), data, {(): 1}))
    hostvars = _hostvars(origin, data, draft)
    for group, entry in data.items():
        if group != "_meta" and not _group(origin.child(group), str(group), entry, draft):
            return     # past the host bound: no `--host` run for each of its hosts
    for host in list(draft.hosts) if hostvars is None else []:
        found = _run(path, ["--host", host], draft, what="the vars of that host (a JSON object of name: value)")
        if found:
            draft.hosts[host].inline.append(make_layer(found, Origin(Doc(str(path), found, {(): 1}))))
    for host, host_vars in (hostvars or {}).items():
        if host in draft.hosts and host_vars:
            draft.hosts[host].inline.append(make_layer(host_vars, origin.child("_meta").child("hostvars")
                                                       .child(host)))


def _hostvars(origin: Origin, data: dict[str, Any], draft: Draft) -> dict[str, dict[str, Any]] | None:
    """`_meta.hostvars` checked: None when absent (then each host is asked `--host NAME`, as Ansible
    does), else host name -> mapping of vars (a null is no vars); a wrong shape is refused by key."""
    shape = "must be {hostvars: {HOST: {NAME: VALUE, ..}, ..}}: fix the script"
    meta = data.get("_meta")
    if meta is None:
        return None
    if not isinstance(meta, dict):
        draft.problems.append(origin.problem(("_meta",), f"{_kind(meta)} in the script's output: _meta {shape}"))
        return {}
    hostvars = meta.get("hostvars")
    if hostvars is None:
        return None
    if not isinstance(hostvars, dict):
        draft.problems.append(origin.problem(("_meta", "hostvars"), f"{_kind(hostvars)} in the script's output: "
                                             "_meta.hostvars must be a mapping of host name -> mapping of its vars "
                                             "({HOST: {NAME: VALUE, ..}, ..}): fix the script"))
        return {}
    out: dict[str, dict[str, Any]] = {}
    for host, host_vars in hostvars.items():
        if host_vars is not None and not isinstance(host_vars, dict):
            draft.problems.append(origin.problem(("_meta", "hostvars", host), f"{_kind(host_vars)} in the script's "
                                                 "output: the vars of a host must be a mapping of name: value: "
                                                 "fix the script"))
            continue
        out[host] = host_vars or {}
    return out


def _kind(value: Any) -> str:
    kinds = {dict: "a mapping", list: "a list", str: "a string", bool: "a boolean", int: "a number",
             float: "a number", type(None): "null"}
    return kinds.get(type(value), type(value).__name__)


def _group(origin: Origin, name: str, entry: Any, draft: Draft) -> bool:
    """One group of the JSON, in Ansible's three shapes: a host list, {hosts, vars, children}, or vars.
    False once the output names more hosts than an inventory may hold (ranges.MAX_HOSTS): only its
    64 MB bounded them, a few million names."""
    if not valid_name(name, origin, draft, "group"):
        return True
    draft.group(name, origin.where)
    if not isinstance(entry, dict):
        entry = {"hosts": entry}
    elif not any(key in entry for key in ("hosts", "vars", "children")):
        entry = {"hosts": [name], "vars": entry}
    hosts, group_vars, children = entry.get("hosts"), entry.get("vars"), entry.get("children")
    bad = [(key, value, want) for key, value, want in (("hosts", hosts, "a list of host names"),
                                                        ("vars", group_vars, "a mapping of name: value"),
                                                        ("children", children, "a list of group names"))
           if value is not None and not isinstance(value, dict if key == "vars" else list)]
    for key, value, want in bad:
        draft.problems.append(origin.problem((key,), f"{_kind(value)} in the script's output: {key} must be {want} "
                                                     "(a group is {hosts: [..], vars: {..}, children: [..]}, or a "
                                                     "list of host names): fix the script"))
    if bad:
        return True
    for index, host in enumerate(hosts or []):
        # Ansible refuses a host name that is no string ("Invalid host name supplied, expected a
        # string"): 1 or null would become a robot named "1" or "None".
        if _string_name(host, origin.child("hosts").child(index), draft, "host") \
                and valid_name(host, origin, draft, "host"):
            if host not in draft.hosts and len(draft.hosts) >= ranges.MAX_HOSTS:
                draft.problems.append(origin.problem(("hosts", index), f"the script's output names more than "
                                                     f"{ranges.MAX_HOSTS} hosts, the most an inventory may hold: "
                                                     "fix the script"))
                return False
            draft.add_host(name, host, origin, None)
    if group_vars:
        draft.groups[name].inline.append(make_layer(group_vars, origin.child("vars")))
    for index, child in enumerate(children or []):
        if _string_name(child, origin.child("children").child(index), draft, "group") \
                and valid_name(child, origin, draft, "group"):
            draft.group(child, origin.where)
            draft.groups[name].children.setdefault(child, origin)
    return True


def _string_name(value: Any, origin: Origin, draft: Draft, what: str) -> bool:
    if isinstance(value, str):
        return True
    shown = json.dumps(value) if isinstance(value, (int, float, bool)) or value is None else _kind(value)
    draft.problems.append(origin.problem((), f"{what} name {shown} in the script's output is not a string, "
                                             f"as Ansible requires: print the {what} names as JSON strings"))
    return False


def _run(path: Path, args: list[str], draft: Draft,
         what: str = "a JSON object of groups") -> dict[str, Any] | None:
    def refuse(message: str) -> dict[str, Any] | None:
        draft.problems.append(Problem(str(path), None, "", f"dynamic inventory script: {message}"))
        return None

    command = f"`{path.name} {' '.join(args)}`"
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        try:
            # Its own session, so a timeout stops whatever it started too, not only the script.
            proc = subprocess.Popen([str(path.absolute()), *args], stdin=subprocess.DEVNULL, stdout=out,
                                    stderr=err, start_new_session=True, env=script_environment())
        except OSError as exc:
            return refuse(f"cannot run it ({exc.strerror}): check its #! line, or remove its execute bit if it "
                          "is not a script")
        stopped = wait(proc, out.fileno(), err.fileno())
        if stopped == "time":
            return refuse(f"{command} did not finish within {TIMEOUT:g} s: fix the script or export its output "
                          "to a YAML file")
        if stopped == "size":
            return refuse(_too_long(command, os.fstat(err.fileno()).st_size > MAX_OUTPUT, what))
        out.seek(0)
        err.seek(max(0, os.fstat(err.fileno()).st_size - 4 * MAX_STDERR))   # only its end is quoted
        stdout, stderr = out.read(), err.read()
    if proc.returncode != 0:
        return refuse(f"{command} exited {proc.returncode}{_stderr_tail(stderr)}")
    try:
        data = json.loads(stdout.decode("utf-8"))
    except RecursionError:
        return refuse(f"{command} printed JSON nested too deeply (more than {MAX_DEPTH} levels): a dynamic "
                      "inventory prints a JSON object of groups; fix the script")
    except (UnicodeDecodeError, ValueError) as exc:
        return refuse(f"{command} did not print JSON ({exc}): a dynamic inventory prints {what}")
    if not isinstance(data, dict):
        return refuse(f"{command} printed {_kind(data)}: its output must be {what}")
    if _too_deep(data):
        return refuse(f"{command} printed JSON nested too deeply (more than {MAX_DEPTH} levels): fix the script")
    found = _not_text_at(data, ())
    if found is not None:   # json.loads reads a lone `\\ud800`; no file rosdeploy writes can hold it
        return refuse(f"{command} printed a value at {dotted(found[0]) or 'the top'} that {found[1]}")
    return data


def _too_long(command: str, on_stderr: bool, what: str) -> str:
    """Which stream ran past MAX_OUTPUT: a script logging without end on stderr is not told that
    its JSON is too long."""
    bound = f"{command} printed more than {MAX_OUTPUT >> 20} MB"
    if on_stderr:
        return (f"{bound} on stderr (its messages; the inventory is read from stdout): quiet its logging or "
                "send it to a file, or export the script's output to a YAML file")
    return f"{bound} on stdout: a dynamic inventory prints {what}; fix the script or export its output to a YAML file"


def _not_text_at(value: Any, keypath: KeyPath) -> tuple[KeyPath, str] | None:
    """The first key path (and why) whose key or value no file can hold (yamlsrc.not_text); the
    data is at most MAX_DEPTH deep, checked before."""
    if isinstance(value, dict):
        for key, item in value.items():
            found = _not_text_at(key, keypath) or _not_text_at(item, keypath + (key,))
            if found is not None:
                return found
        return None
    if isinstance(value, list):
        return next((f for i, item in enumerate(value) if (f := _not_text_at(item, keypath + (i,)))), None)
    why = not_text(value, controls=True)
    return None if why is None else (keypath, why)


def script_environment() -> dict[str, str]:
    """The environment without rosdeploy's vault password: it is rosdeploy's, not the script's,
    and a script that echoes its environment would put it in an error message."""
    return {name: value for name, value in os.environ.items() if name not in PRIVATE_ENV}


def _stderr_tail(stderr: bytes) -> str:
    """The end of what the script printed to stderr, at most MAX_STDERR characters, on one line."""
    text = stderr.decode("utf-8", "replace").strip()
    if not text:
        return ""
    cut = len(text) > MAX_STDERR
    text = " | ".join(line.strip() for line in text[-MAX_STDERR:].splitlines() if line.strip())
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return f": {'...' if cut else ''}{text}"


def _too_deep(data: Any) -> bool:
    """Nested past MAX_DEPTH (the bound YAML files have): later steps walk values recursively."""
    stack = [(data, 1)]
    while stack:
        value, depth = stack.pop()
        if depth > MAX_DEPTH:
            return True
        if isinstance(value, dict):
            stack.extend((item, depth + 1) for item in value.values())
        elif isinstance(value, list):
            stack.extend((item, depth + 1) for item in value)
    return False


def wait(proc: subprocess.Popen, *outputs: int, timeout: float | None = None, limit: int | None = None) -> str:
    """Wait for a script started in its own session: "" when it exited, "time" or "size" when it
    was stopped (with everything it started) for running past `timeout` (TIMEOUT) or printing more
    than `limit` (MAX_OUTPUT) bytes into one of `outputs` (each bounded alone, so that the caller
    can say which one ran over). The output goes to files, not pipes, so its size is known without
    reading it."""
    deadline = time.monotonic() + (TIMEOUT if timeout is None else timeout)
    limit = MAX_OUTPUT if limit is None else limit
    while True:
        try:
            proc.wait(timeout=POLL)
            stopped = ""
        except subprocess.TimeoutExpired:
            stopped = "time" if time.monotonic() > deadline else ""
        if any(os.fstat(fd).st_size > limit for fd in outputs):
            stopped = "size"
        if stopped or proc.returncode is not None:
            break
    if stopped:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    return stopped
