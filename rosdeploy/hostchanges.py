"""Host changes: what a release changes outside its own directory, with the right privileges.

- the udev rules (99-rosdeploy.rules): installed to /etc/udev/rules.d as
  99-rosdeploy-<project>.rules, syntax-checked with `udevadm verify` where it exists, the
  rules reloaded and the subsystems triggered where udev runs. A robot without udev (a
  container, the sim) gets a note, not a failure: the rules still land. Then every mapped
  device must resolve before anything restarts (a device the new rules create included).
- the ROS log rotation (rotation.py): logrotate.conf as /etc/logrotate.d/rosdeploy-<project>,
  logrotate.cron as /etc/cron.d/rosdeploy-<project>.

The files installed are always those of a release directory, so host changes are versioned
with the release: a rollback installs the kept release's again. Nothing that differs from
what is installed: no root needed (the comparison runs as the SSH user).

Privileges: as root directly; as another user through sudo, as Ansible's become does:
`ansible_become` (false refuses), `ansible_become_user` (must be root),
`ansible_become_method` (only sudo), `ansible_become_password`/`ansible_become_pass` (from
a vault) or --ask-become-pass: `sudo -S` with the password on stdin; else `sudo -n`,
which never waits for a password. `check` says, per robot and before anything changes,
exactly what is missing and how to grant it.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any, Mapping

from rosdeploy import rotation
from rosdeploy.commands import Command, load, script
from rosdeploy.model import FleetSpec, Host, RenderedRelease

RULES_FILE = "99-rosdeploy.rules"
RULES_DIR = "/etc/udev/rules.d"
NOTHING = "host changes unchanged"     # what install says when nothing differed (and no device to check)
NO_ROOT = 3                             # ... when something differs and root is refused (Become.refused)
MISSING_DEVICE = 7                      # exit status of the install script when a mapped device is missing


# Run as the SSH user (with the scripts' prologue): what differs, whether root is reachable, the tools.
CHECK_SCRIPT = load("hostchanges-check.sh")
# Run as the SSH user: become root for ROOT_SCRIPT when something differs, then check the devices.
INSTALL_SCRIPT = load("hostchanges-install.sh")
# Run as root: install or remove the files, verify, reload and trigger udev.
ROOT_SCRIPT = load("hostchanges-root.sh")
# Run by the deploy guard (guard.sh) when it goes back to a release: left on the robot by INSTALL_SCRIPT.
RESTORE_SCRIPT = load("hostchanges-restore.sh")


@dataclass(frozen=True)
class Become:
    """How root is reached on one robot: mode is direct | sudo-n | sudo-S; `refused` says why not."""

    mode: str
    password: str | None = None
    refused: str = ""


def become(host: Host, asked_password: str | None = None) -> Become:
    v: Mapping[str, Any] = host.vars
    from rosdeploy.inventory.templating import shown_unless_secret
    named, read = _read(v, "ansible_user")
    user = host.user or str(named or "")
    if user == "root":
        return Become("direct")
    if not _become_on(v.get("ansible_become", True)):
        who = "the SSH user" if read or not user else user
        return Become("", refused=f"ansible_become is false for {who}, who is not root: set "
                                  "ansible_become: true (and grant sudo), connect as root, or pass --no-host-changes")
    target, read = _read(v, "ansible_become_user")
    if str(target or "root") != "root":
        return Become("", refused=f"ansible_become_user is {shown_unless_secret(str(target), read)}: host "
                                  "changes need root")
    method, read = _read(v, "ansible_become_method")
    if str(method or "sudo") != "sudo":
        return Become("", refused=f"ansible_become_method {shown_unless_secret(str(method), read)} is not "
                                  "supported: use sudo")
    password = asked_password or v.get("ansible_become_password") or v.get("ansible_become_pass")
    return Become("sudo-S", str(password)) if password else Become("sudo-n")


def _become_on(value: Any) -> bool:
    """ansible_become as Ansible reads it (the inventory makes it a bool at load: hostvars.ANSIBLE_READ).
    A value that is neither true nor false never gets past the load; here it does not become."""
    from rosdeploy.inventory.hostvars import BadValue, ansible_bool
    try:
        return ansible_bool(value)
    except BadValue:
        return False


def _read(v: Mapping[str, Any], name: str) -> tuple[Any, dict[str, str]]:
    """An inventory var, and the vault vars computing it read (its value is never shown then)."""
    from rosdeploy.inventory.templating import secret_reads
    with secret_reads() as read:
        value = v.get(name)
    return value, read


def rules_name(project: str) -> str:
    return f"99-rosdeploy-{project}.rules"


def targets(project: str) -> tuple[str, str, str]:
    """Where the release's udev rules, rotation config and rotation schedule are installed."""
    name = rotation.installed_name(project)
    return (f"{RULES_DIR}/{rules_name(project)}", f"{rotation.CONF_DIR}/{name}", f"{rotation.CRON_DIR}/{name}")


def has_content(text: str) -> bool:
    """A file of only comments and blank lines installs nothing (and removes what is installed)."""
    return any(line.strip() and not line.lstrip().startswith("#") for line in text.splitlines())


def _content(release: RenderedRelease, name: str) -> str:
    return next((f.content for f in release.files if f.name == name), "")


def has_rules(release: RenderedRelease) -> bool:
    return has_content(_content(release, RULES_FILE))


def schedule(release: RenderedRelease) -> str | None:
    """The rotation's cron line, or None when the release has no schedule (rotate_every: off)."""
    jobs = [line for line in _content(release, rotation.CRON_FILE).splitlines()
            if line.strip() and not line.startswith("#") and "=" not in line.split(" ", 1)[0]]
    return jobs[0] if jobs else None


def wanted(release: RenderedRelease, project: str) -> dict[str, str | None]:
    """Target -> the content the release installs there (None: the release wants none)."""
    rules, conf, cron = targets(project)
    rotates = schedule(release) is not None
    return {rules: _content(release, RULES_FILE) if has_rules(release) else None,
            conf: _content(release, rotation.CONF_FILE) if rotates else None,
            cron: _content(release, rotation.CRON_FILE) if rotates else None}


def describe(release: RenderedRelease, project: str) -> tuple[str, ...]:
    """What `plan` lists under host changes."""
    rules, conf, cron = targets(project)
    out = []
    if has_rules(release):
        out.append(f"install udev rules {rules} (reload udev, trigger subsystems)")
    job = schedule(release)
    if job is not None:
        out.append(f"install log rotation {conf}, run by {cron} (`{' '.join(job.split()[:5])}`, as root, "
                   f"state {rotation.state_file(project)})")
    return tuple(out)


def drift(installed: Mapping[str, str] | None, release: RenderedRelease, project: str) -> tuple[str, ...]:
    """The host-change files on the robot that differ from what `release` installs: changed, removed, or
    present where the release wants none. () when the state did not look, and for a file it cannot read."""
    if installed is None:
        return ()
    out = []
    for target, text in wanted(release, project).items():
        have = installed.get(target)
        want = hashlib.sha256(text.encode()).hexdigest() if text is not None else None
        if have != "?" and have != want:
            out.append(target)
    return tuple(out)


def mapped_devices(spec: FleetSpec, host: Host) -> tuple[str, ...]:
    """The robot paths of the devices the services use (what must resolve before anything restarts)."""
    used = {d for s in spec.services for d in s.devices}
    return tuple(sorted(host.devices[d] for d in used if d in host.devices))


def made_by_rules(host: Host) -> frozenset[str]:
    """The /dev paths this robot's udev rules create: checked after the trigger, not before."""
    return frozenset(f"/dev/{u.symlink}" for u in host.udev)


def check_command(root: str, project: str, how: Become, want: dict[str, str | None]) -> Command:
    pairs = [item for target, text in want.items()
             for item in (target, hashlib.sha256(text.encode()).hexdigest() if text is not None else "-")]
    return _with_password(script("host-check", CHECK_SCRIPT, root, project, how.mode, *pairs), how)


def _facts(stdout: str) -> tuple[list[str], dict[str, str]]:
    """(targets that differ, the other `key value` lines)."""
    lines = [line.split(" ", 1) for line in stdout.splitlines() if " " in line]
    return [v for k, v in lines if k == "differs"], {k: v for k, v in lines if k != "differs"}


def problems(stdout: str, host: Host, how: Become, rotates: bool) -> list[str]:
    """Why the host changes cannot be made; [] when they can, or when none differ."""
    differ, facts = _facts(stdout)
    out = []
    if rotates and facts.get("logrotate") == "no":
        out.append(f"{host.name} has no logrotate, which the ROS log rotation runs: install it "
                   "(`apt-get install logrotate`), or set `logging.rotate_every: off` in the fleet file")
    if rotates and facts.get("cron") == "no":
        out.append(f"{host.name} has no cron (/usr/sbin/cron or crond, and /etc/cron.d), which runs the ROS log "
                   "rotation between deploys: install it (`apt-get install cron`) and start it, or set "
                   "`logging.rotate_every: off` in the fleet file")
    if not differ:
        return out
    what = f"host changes ({', '.join(differ)})"
    if how.refused:
        return out + [f"{what}: {how.refused}"]
    return out + _root_problems(facts.get("root", ""), what, host)


def _root_problems(root: str, what: str, host: Host) -> list[str]:
    user = host.user or "the SSH user"
    if root == "ok":
        return []
    grant = (f"grant it with a sudoers entry such as `{user} ALL=(root) NOPASSWD: ALL` in /etc/sudoers.d/, "
             "set ansible_become_password (in a vault), pass --ask-become-pass, or skip them with --no-host-changes")
    if root == "no-sudo":
        return [f"{what} need root, and {user} is not root and sudo is not installed: install sudo and {grant}"]
    if root.startswith("denied"):
        why = root.removeprefix("denied").strip()[:200]
        return [f"{what} need root, and `sudo` refused {user} ({why}): {grant}"]
    return [f"{what} need root, and the robot did not say whether {user} can have it: {grant}"]


def install_command(root: str, project: str, release: str, how: Become, subsystems: tuple[str, ...],
                    devices: tuple[str, ...] = ()) -> Command:
    """Install `release`'s host changes; then check that `devices` resolve."""
    rules, conf, cron = targets(project)
    cmd = script("host-install", INSTALL_SCRIPT, root, project, release, how.mode or "refused", ROOT_SCRIPT,
                 ",".join(sorted(set(subsystems))), rules, conf, cron, rotation.STATE_DIR, RESTORE_SCRIPT, *devices)
    return _with_password(cmd, how)


def _with_password(cmd: Command, how: Become) -> Command:
    """The sudo password on stdin (sudo -S reads one line), never in argv."""
    if how.mode != "sudo-S" or how.password is None:
        return cmd
    return Command(cmd.argv, stdin=(how.password + "\n").encode(), timeout=cmd.timeout, label=cmd.label)


def missing_devices(stdout: str, host: Host,
                    when: str = "after the udev rules were installed and triggered") -> list[str]:
    """A message per mapped device that did not resolve (`missing-device PATH` lines)."""
    names = {path: name for name, path in host.devices.items()}
    rules = {f"/dev/{u.symlink}": u for u in host.udev}
    out = []
    for path in (line.split(" ", 1)[1] for line in stdout.splitlines() if line.startswith("missing-device ")):
        rule = rules.get(path)
        made = (f"the udev rule SYMLINK+=\"{rule.symlink}\" for {rule.vendor}:{rule.product}"
                + (f" serial {rule.serial}" if rule.serial else "") + " (`udev` in the inventory) did not create it"
                if rule else "no udev rule of this robot creates it")
        out.append(f"device {path} (`devices.{names.get(path, '?')}` in the inventory) is missing on {host.name} "
                   f"{when}: {made}; plug it in, check the rule's ids "
                   "(`udevadm info -a -n <device>`), or fix the inventory")
    return out


# ------------------------------------------------------------- the deploy's calls

def preflight(t: Any, root: str, project: str, host: Host, release: RenderedRelease,
              password: str | None = None, missing: tuple[str, ...] = ()) -> list[str]:
    """Per robot, before anything changes: can the host changes be made? (one round trip)
    `missing`: mapped devices not there now. One a udev rule makes waits for the trigger,
    unless the rules are already installed as they are: then no trigger will come."""
    how = become(host, password)
    out = t.run(check_command(root, project, how, wanted(release, project)))
    found = problems(out.stdout, host, how, schedule(release) is not None)
    if targets(project)[0] not in _facts(out.stdout)[0]:
        lines = "".join(f"missing-device {p}\n" for p in missing if p in made_by_rules(host))
        found += missing_devices(lines, host, when="with its udev rule installed already")
    return found


def install(t: Any, root: str, project: str, release: str, host: Host, password: str | None = None,
            devices: tuple[str, ...] = ()) -> tuple[bool, str]:
    """Install `release`'s host changes, then check that `devices` resolve: (ok, notes).
    Nothing that differs costs one round trip and no root."""
    how = become(host, password)
    out = t.run(install_command(root, project, release, how, tuple(u.subsystem for u in host.udev), devices))
    if how.refused and out.exited == NO_ROOT:
        return False, how.refused
    missing = missing_devices(out.stdout, host) if out.exited == MISSING_DEVICE else []
    lines = [line.strip() for line in (out.stdout + out.stderr).splitlines()
             if line.strip() and not line.startswith("missing-device ")]
    return out.ok, "; ".join(missing + lines)
