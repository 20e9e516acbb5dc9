"""Host changes: what a release changes outside its own directory, with the right privileges.

Today that is the udev rules (99-rosdeploy.rules): installed to /etc/udev/rules.d as
99-rosdeploy-<project>.rules, syntax-checked with `udevadm verify` where it exists, the
rules reloaded and the subsystems triggered where udev runs. A robot without udev (a
container, the sim) gets a note, not a failure: the rules still land.

The file installed is always the one in a release directory, so host changes are versioned
with the release: a rollback installs the kept release's rules again.

Privileges: as root directly; as another user through sudo, as Ansible's become does:
`ansible_become` (false refuses), `ansible_become_user` (must be root),
`ansible_become_method` (only sudo), `ansible_become_password`/`ansible_become_pass` (from
a vault) or --ask-become-pass: `sudo -S` with the password on stdin; else `sudo -n`,
which never waits for a password. `check` says, per robot and before anything changes,
exactly what is missing and how to grant it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from rosdeploy.commands import _PROLOGUE, Command, script
from rosdeploy.model import Host, RenderedRelease

RULES_FILE = "99-rosdeploy.rules"
RULES_DIR = "/etc/udev/rules.d"
NOTHING = "no udev rules"     # what install says when there was nothing to install or remove


@dataclass(frozen=True)
class Become:
    """How root is reached on one robot: mode is direct | sudo-n | sudo-S; `refused` says why not."""

    mode: str
    password: str | None = None
    refused: str = ""


def become(host: Host, asked_password: str | None = None) -> Become:
    v: Mapping[str, Any] = host.vars
    user = host.user or str(v.get("ansible_user") or "")
    if user == "root":
        return Become("direct")
    if str(v.get("ansible_become", "true")).lower() in ("false", "no", "0"):
        return Become("", refused=f"ansible_become is false for {user or 'the SSH user'}, who is not root: set "
                                  "ansible_become: true (and grant sudo), connect as root, or pass --no-host-changes")
    target = str(v.get("ansible_become_user") or "root")
    if target != "root":
        return Become("", refused=f"ansible_become_user is {target!r}: installing udev rules needs root")
    method = str(v.get("ansible_become_method") or "sudo")
    if method != "sudo":
        return Become("", refused=f"ansible_become_method {method!r} is not supported: use sudo")
    password = asked_password or v.get("ansible_become_password") or v.get("ansible_become_pass")
    return Become("sudo-S", str(password)) if password else Become("sudo-n")


def rules_name(project: str) -> str:
    return f"99-rosdeploy-{project}.rules"


def has_rules(release: RenderedRelease) -> bool:
    content = next((f.content for f in release.files if f.name == RULES_FILE), "")
    return any(line.strip() and not line.lstrip().startswith("#") for line in content.splitlines())


def describe(release: RenderedRelease, project: str) -> tuple[str, ...]:
    """What `plan` lists under host changes."""
    if not has_rules(release):
        return ()
    return (f"install udev rules {RULES_DIR}/{rules_name(project)} (reload udev, trigger subsystems)",)


# Run as the SSH user: say whether the rules differ from what is installed and whether root
# is reachable (sudo -n/-S true), without changing anything.
CHECK_SCRIPT = _PROLOGUE + r'''
mode=$1; want=$2; name=$3
installed=$RULES_DIR/$name
[ -f "$installed" ] && echo "installed yes" || echo "installed no"
case $mode in
  direct) [ "$(id -u)" = 0 ] && echo "root ok" || echo "root not-root" ;;
  sudo-n)
    if ! command -v sudo >/dev/null 2>&1; then echo "root no-sudo"
    elif err=$(sudo -n true 2>&1); then echo "root ok"
    else echo "root denied $err" | tr '\n' ' '; echo; fi ;;
  sudo-S)
    if ! command -v sudo >/dev/null 2>&1; then echo "root no-sudo"
    elif err=$(sudo -S -p '' true 2>&1); then echo "root ok"
    else echo "root denied $err" | tr '\n' ' '; echo; fi ;;
esac
command -v udevadm >/dev/null 2>&1 && echo "udevadm yes" || echo "udevadm no"
echo "want $want"
'''.replace("$RULES_DIR", RULES_DIR)


def check_command(root: str, project: str, how: Become, wanted: bool) -> Command:
    cmd = script("host-check", CHECK_SCRIPT, root, project, how.mode, "yes" if wanted else "no", rules_name(project))
    return _with_password(cmd, how)


def problems(stdout: str, host: Host, how: Become, wanted: bool) -> list[str]:
    """Why the host changes cannot be made; [] when they can, or when none are needed."""
    facts = dict(line.split(" ", 1) for line in stdout.splitlines() if " " in line)
    if not wanted and facts.get("installed") != "yes":
        return []
    if how.refused:
        return [f"host changes (udev rules): {how.refused}"]
    root = facts.get("root", "")
    user = host.user or "the SSH user"
    if root == "ok":
        return []
    grant = (f"grant it with a sudoers entry such as `{user} ALL=(root) NOPASSWD: ALL` in /etc/sudoers.d/, "
             "set ansible_become_password (in a vault), pass --ask-become-pass, or skip them with --no-host-changes")
    if root == "no-sudo":
        return [f"host changes (udev rules) need root, and {user} is not root and sudo is not installed: install "
                f"sudo and {grant}"]
    if root.startswith("denied"):
        why = root.removeprefix("denied").strip()[:200]
        return [f"host changes (udev rules) need root, and `sudo` refused {user} ({why}): {grant}"]
    return [f"host changes (udev rules) need root, and the robot did not say whether {user} can have it: {grant}"]


# Run as root (directly or through sudo): install the release's rules if they differ, keep the
# previous ones for `restore`, verify, reload, trigger. Notes go to stdout, one per line.
INSTALL_SCRIPT = r'''
set -u
src=$1; name=$2; shift 2
dst=$RULES_DIR/$name
mkdir -p $RULES_DIR
if [ ! -s "$src" ] || ! grep -qv '^[[:space:]]*\(#.*\)\{0,1\}$' "$src"; then
  if [ -f "$dst" ]; then rm -f "$dst"; echo "removed $dst"; changed=1; else echo "no udev rules"; exit 0; fi
elif [ -f "$dst" ] && cmp -s "$src" "$dst"; then
  echo "udev rules unchanged"; changed=0
else
  cp "$src" "$dst.tmp" && chmod 0644 "$dst.tmp" && mv "$dst.tmp" "$dst" || exit 5
  echo "installed $dst"; changed=1
fi
if command -v udevadm >/dev/null 2>&1; then
  if [ -f "$dst" ] && udevadm verify --help >/dev/null 2>&1; then
    udevadm verify "$dst" >/dev/null 2>&1 && echo "udevadm verify: ok" || { echo "udevadm verify failed"; exit 6; }
  fi
  if [ -S /run/udev/control ]; then
    if [ "$changed" = 0 ]; then :
    elif udevadm control --reload-rules && udevadm trigger --action=change "$@" && udevadm settle -t 10; then
      echo "udev rules reloaded"
    else echo "udev reload failed"; fi
  else
    echo "note: udevd is not running here; rules installed, not loaded"
  fi
else
  echo "note: no udev on this robot (a container?); rules installed, not loaded"
fi
'''.replace("$RULES_DIR", RULES_DIR)

# As the SSH user: resolve the release's rules path (~ is this user's home), then become root.
INSTALL_OUTER = _PROLOGUE + r'''
release=$1; mode=$2; name=$3; inner=$4; shift 4
src=$dir/releases/$release/$RULES_FILE
[ -d "$dir/releases/$release" ] || { echo "release $release is not on this robot" >&2; exit 4; }
# Nothing to install and nothing to remove: no need for root (a robot without sudo deploys as before).
if ! grep -qv '^[[:space:]]*\(#.*\)\{0,1\}$' "$src" 2>/dev/null && [ ! -f "$RULES_DIR/$name" ]; then
  echo "no udev rules"; exit 0
fi
case $mode in
  direct) exec sh -c "$inner" rosdeploy "$src" "$name" "$@" ;;
  sudo-n) exec sudo -n sh -c "$inner" rosdeploy "$src" "$name" "$@" ;;
  sudo-S) exec sudo -S -p '' sh -c "$inner" rosdeploy "$src" "$name" "$@" ;;
esac
'''.replace("$RULES_FILE", RULES_FILE).replace("$RULES_DIR", RULES_DIR)


def install_command(root: str, project: str, release: str, how: Become, subsystems: tuple[str, ...]) -> Command:
    triggers = tuple(f"--subsystem-match={s}" for s in sorted(set(subsystems)))
    cmd = script("host-install", INSTALL_OUTER, root, project, release, how.mode, rules_name(project),
                 INSTALL_SCRIPT, *triggers)
    return _with_password(cmd, how)


def _with_password(cmd: Command, how: Become) -> Command:
    """The sudo password on stdin (sudo -S reads one line), never in argv."""
    if how.mode != "sudo-S" or how.password is None:
        return cmd
    return Command(cmd.argv, stdin=(how.password + "\n").encode(), timeout=cmd.timeout, label=cmd.label)


# ------------------------------------------------------------- the deploy's calls

def preflight(t: Any, root: str, project: str, host: Host, release: RenderedRelease,
              password: str | None = None) -> list[str]:
    """Per robot, before anything changes: can the host changes be made? (one round trip)"""
    how, wanted = become(host, password), has_rules(release)
    out = t.run(check_command(root, project, how, wanted))
    return problems(out.stdout, host, how, wanted)


def install(t: Any, root: str, project: str, release: str, host: Host, password: str | None = None) -> tuple[bool, str]:
    """Install `release`'s host changes: (ok, notes). Nothing to do costs one round trip, no root."""
    subsystems = tuple(u.subsystem for u in host.udev)
    how = become(host, password)
    if how.refused:
        return False, how.refused
    out = t.run(install_command(root, project, release, how, subsystems))
    notes = "; ".join(line.strip() for line in (out.stdout + out.stderr).splitlines() if line.strip())
    return out.ok, notes
