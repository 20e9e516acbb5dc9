"""Pure builders of every command rosdeploy runs on a robot.

Each remote step is a FIXED POSIX sh script; everything that comes from the
inventory or the fleet file reaches it only as a positional argument, quoted
with shlex.quote. No value is ever spliced into shell text, so a device path
or a project name cannot become code whatever it contains. Tests assert the
argv tuples built here; transport.py runs them. The scripts are files in
rosdeploy/scripts/ (package data, checked by shellcheck), read once at import.
"""
from __future__ import annotations

import json
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

PROG = "rosdeploy"   # $0 of every script: shows up in `ps` on the robot
SCRIPTS = Path(__file__).parent / "scripts"
_INCLUDE = re.compile(r"\. \./(_[a-z0-9-]+\.sh)\n?")
LOADED: set[str] = set()   # every file under SCRIPTS a script was made of (the tests check none is left over)


def load(name: str) -> str:
    """The robot script SCRIPTS/NAME as it is sent: made of its file and the fragments it includes.

    A `. ./_x.sh` line (shellcheck follows it, so it checks the script with the fragment's
    definitions) becomes that fragment's text, once per script: a fragment includes the ones
    it needs, and a script that has them already does not get them twice. Lines for people
    and the linter stay at home: the file's opening comment block (up to its first blank
    line) and every `# shellcheck` directive.
    """
    return _load(name, set())


def _load(name: str, seen: set[str]) -> str:
    seen.add(name)
    LOADED.add(name)
    out, opening = [], True
    for line in (SCRIPTS / name).read_text(encoding="utf-8").splitlines(keepends=True):
        opening = opening and bool(line.strip())
        include = _INCLUDE.fullmatch(line)
        if include:
            out.append("" if include[1] in seen else _load(include[1], seen))
        elif not ((opening and line.startswith("#")) or line.lstrip().startswith("# shellcheck ")):
            out.append(line)
    return "".join(out)


@dataclass(frozen=True)
class Command:
    argv: tuple[str, ...]
    stdin: bytes | None = None
    timeout: float | None = None
    label: str = ""          # what people see instead of the whole script

    def wire(self) -> str:
        """The exact string the remote login shell receives."""
        return " ".join(shlex.quote(a) for a in self.argv)

    def display(self) -> str:
        return self.label or self.wire()


def script(name: str, body: str, *args: str, stdin: bytes | None = None, timeout: float | None = None) -> Command:
    return Command(("sh", "-c", body, PROG, *map(str, args)), stdin=stdin, timeout=timeout,
                   label=f"{name} {' '.join(shlex.quote(str(a)) for a in args)}".strip())


# hostchanges.py starts its own scripts with it
_PROLOGUE = load("_prologue.sh")

STATE_SCRIPT = load("state.sh")


def state(root: str, project: str, devices: tuple[str, ...] = (), compose: str = "auto",
          gpu: bool = False, full: bool = True) -> Command:
    """What apply/plan/status need to know about a robot, in ONE round trip.

    Quick (full=False) is enough to tell a no-op and to show status; full adds the
    preflight facts (Docker and Compose versions, disk, devices, GPU runtime).
    """
    return script("state" if full else "state (quick)", STATE_SCRIPT, root, project,
                  "full" if full else "quick", compose, "yes" if gpu else "no", *devices)


LOCK_SCRIPT = load("lock.sh")

LOCKED_STATE_SCRIPT = load("locked-state.sh")

UNLOCK_SCRIPT = load("unlock.sh")


def lock(root: str, project: str, owner: dict, break_stale: bool = False, dead_run: str = "",
         guard: tuple[str, ...] = (), expect: str | None = None) -> Command:
    """mkdir is atomic on every filesystem: the lock is a directory holding its owner.
    `dead_run`: the run id of a holder proven dead; its lock (only) is removed first.
    `guard`: arm the deploy guard under the lock (see arm_args).
    `expect`: `current`'s link as read before; if it moved, the lock is given back (exit 4, `moved`)."""
    return script("lock", LOCK_SCRIPT, root, project, json.dumps(owner, sort_keys=True),
                  "yes" if break_stale else "no", dead_run, "no" if expect is None else "yes", expect or "",
                  *guard)


def arm_args(state: str, seconds: float, files: tuple[str, ...], images: tuple[str, ...]) -> tuple[str, ...]:
    """The lock's guard arguments: its state text, seconds to its first deadline, its six
    files (guard.sh, up.sh, finish.sh, probe.sh, ros_probe.py, probe.json), and the images
    its container may run from (the current release's are tried first)."""
    return (state, str(int(seconds)), *files, *images)


def locked_state(root: str, project: str, owner: dict, break_stale: bool = False, dead_run: str = "",
                 guard: tuple[str, ...] = ()) -> Command:
    """`lock`, then the state as a rollback needs it (the lock's answer comes first, before
    the sections): one round trip where a rollback made three (state, lock, manifest).
    `guard`: arm the rollback's guard under the lock (arm_args)."""
    return script("lock+state", LOCKED_STATE_SCRIPT, root, project, json.dumps(owner, sort_keys=True),
                  "yes" if break_stale else "no", dead_run, *guard)


def unlock(root: str, project: str, token: str) -> Command:
    return script("unlock", UNLOCK_SCRIPT, root, project, token)


UPLOAD_SCRIPT = load("upload.sh")


def upload(root: str, project: str, release: str, tarball: bytes, services: tuple[str, ...] = (),
           rearm: str = "") -> Command:
    """Files go to a temporary dir and are renamed into place: never half-written.
    `rearm`: "RUN SECONDS", the guard's next deadline (see rearm)."""
    return script("upload", UPLOAD_SCRIPT, root, project, release, rearm, *services, stdin=tarball)


REARM_SCRIPT = load("rearm.sh")


def rearm(root: str, project: str, arm: str) -> Command:
    """Push this run's guard deadline out ("RUN SECONDS"); exit 6 when the guard already acted."""
    return script("rearm", REARM_SCRIPT, root, project, arm)


def rearm_arg(run: str, seconds: float) -> str:
    return f"{run} {int(seconds)}"


PULL_SCRIPT = load("pull.sh")


def pull(images: tuple[str, ...], timeout: float | None = None) -> Command:
    """Pull by versioned tag while the old release keeps running; present images are not pulled again."""
    return script("pull", PULL_SCRIPT, *images, timeout=timeout)


UP_SCRIPT = load("up.sh")


def up(root: str, project: str, release: str, flavor: str, services: tuple[str, ...] = (),
       together: bool = False, timeout: float | None = None, rearm: str = "") -> Command:
    """Switch the compose project to a release: the same project name, so containers are
    replaced. All services the compose way; or only `services`, in that order, without
    waiting on their dependencies; or `together`: every service started at once.
    `rearm`: "RUN SECONDS", the guard's deadline from this start on (exit 6: it took over)."""
    mode = "together" if together else "each" if services else "all"
    return script("up", UP_SCRIPT, root, project, release, flavor, mode, rearm, *services, timeout=timeout)


def started_containers(up_output: str) -> tuple[dict, ...] | None:
    """The containers a successful `up` listed once they were started; None if it listed none."""
    _, mark, listed = up_output.partition("\n@@started\n")
    return parse_containers(listed) if mark else None


def _runnable_test(test: tuple[str, ...]) -> tuple[str, tuple[str, ...]] | None:
    """("CMD", argv) or ("CMD-SHELL", (command,)) from a HEALTHCHECK test; None for NONE
    or a form rosdeploy does not know."""
    kind, args = (test[0], test[1:]) if test else ("NONE", ())
    if kind not in ("CMD", "CMD-SHELL") or not args:
        return None
    return kind, args[:1] if kind == "CMD-SHELL" else args


def health_test(container: str, test: tuple[str, ...], timeout: float) -> Command | None:
    """Run a container's own HEALTHCHECK test now, the way Docker runs it (exec, exit 0 = pass).
    None for NONE or an unknown form. Docker < 25 first runs it one full `interval` after
    the start (no `start_interval`); running it ourselves ends that wait."""
    runnable = _runnable_test(test)
    if runnable is None:
        return None
    kind, args = runnable
    argv = ("docker", "exec", container, *(args if kind == "CMD" else ("/bin/sh", "-c", args[0])))
    return Command(argv, timeout=timeout, label=f"health-test {container}")


HEALTH_WATCH_SCRIPT = load("health-watch.sh")


def health_watch(container: str, test: tuple[str, ...], timeout: float, window: float,
                 every: float) -> Command | None:
    """Run a container's own health test inside it every `every` s for about `window` s,
    until it passes. None for NONE or an unknown form. A try that hangs is bounded by
    the command's timeout (the window plus the test's own timeout)."""
    runnable = _runnable_test(test)
    if runnable is None:
        return None
    kind, args = runnable
    argv = ("docker", "exec", container, "/bin/sh", "-c", HEALTH_WATCH_SCRIPT, "sh",
            str(max(1, round(window / every))), str(max(1, round(every * 100))), kind, *args)
    return Command(argv, timeout=window + timeout + 5.0, label=f"health-watch {container}")


DOWN_SCRIPT = load("down.sh")


def down(root: str, project: str, release: str, flavor: str) -> Command:
    return script("down", DOWN_SCRIPT, root, project, release, flavor)


CONTAINERS_SCRIPT = load("containers.sh")


def containers(project: str, names: tuple[str, ...] = ()) -> Command:
    """One line of JSON per container of the compose project (health gate poll);
    with `names`, only those containers, found without listing the project."""
    return script("containers", CONTAINERS_SCRIPT, project, *names)


def logs(container: str, lines: int = 20) -> Command:
    return Command(("docker", "logs", "--tail", str(lines), container), label=f"logs {container}")


ROS_PROBE_SCRIPT = load("ros-probe.sh")


def ros_probe(container: str, probe_source: str, spec: dict, timeout: float) -> Command:
    """Run rosdeploy's rclpy probe inside a running container of the release.

    ROS images need their setup sourced; images with rclpy on the default path
    (pip-installed ROS) work as they are.
    """
    return script("ros-probe", ROS_PROBE_SCRIPT, container, probe_source, json.dumps(spec, sort_keys=True),
                  timeout=timeout)


FINISH_SCRIPT = load("finish.sh")


def finish(root: str, project: str, release: str, record: dict, keep: int, guard_run: str = "") -> Command:
    """Point `current` at the release (atomic rename), append history, prune old releases.
    `guard_run`: disarm this run's guard first (exit 6 if it took over)."""
    return script("activate", FINISH_SCRIPT, root, project, release,
                  json.dumps(record, sort_keys=True), str(keep), guard_run)


RECORD_SCRIPT = load("record.sh")


def record(root: str, project: str, entry: dict, rearm: str = "") -> Command:
    """Append to history without switching anything (failed deploys, rollbacks that failed).
    `rearm`: "RUN SECONDS", a new deadline for the guard (the run goes on: its own rollback)."""
    return script("history", RECORD_SCRIPT, root, project, json.dumps(entry, sort_keys=True), rearm)





def parse_sections(stdout: str) -> dict[str, str]:
    """Split `@@name` sections of the state script into a dict of their bodies."""
    sections: dict[str, str] = {}
    name = None
    lines: list[str] = []
    for line in stdout.splitlines():
        if line.startswith("@@"):
            if name is not None:
                sections[name] = "\n".join(lines).strip()
            name, lines = line[2:].strip(), []
        elif name is not None:
            lines.append(line)
    return sections


def parse_containers(text: str) -> tuple[dict, ...]:
    """Containers from `docker ps`/`docker inspect` lines (one JSON object each) or from
    the Engine API's container list (one JSON array), as dicts with the same keys."""
    out = []
    for line in text.splitlines():
        line = line.strip()
        try:
            if line.startswith("{"):
                out.append(json.loads(line))
            elif line.startswith("["):
                out.extend(_from_engine_api(c) for c in json.loads(line))
        except (ValueError, TypeError, AttributeError):
            continue
    return tuple(sorted(out, key=lambda c: c.get("name", "")))


def _from_engine_api(c: dict) -> dict:
    labels = c.get("Labels") or {}
    return {"name": ((c.get("Names") or [""])[0]).lstrip("/"), "service": labels.get("com.docker.compose.service"),
            "image": c.get("Image", ""), "status": c.get("State", ""), "ps_status": c.get("Status", ""),
            "workdir": labels.get("com.docker.compose.project.working_dir"),
            "compose": labels.get("com.docker.compose.version")}


MANIFEST_SCRIPT = load("manifest.sh")


def manifest(root: str, project: str, release: str) -> Command:
    """A kept release's manifest.json (empty output when it has none)."""
    return script("manifest", MANIFEST_SCRIPT, root, project, release)


RELEASE_FILES_SCRIPT = load("release-files.sh")


def release_files(root: str, project: str, release: str, names: tuple[str, ...], images: tuple[str, ...]) -> Command:
    """The files of a kept release (for plan's diff) and which of `images` the robot lacks.

    Images travel on stdin, one per line, so the argv stays one list of file names.
    """
    return script("read-release", RELEASE_FILES_SCRIPT, root, project, release, *names,
                  stdin="".join(f"{i}\n" for i in images).encode())
