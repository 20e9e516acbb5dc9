"""Pure builders of every command rosdeploy runs on a robot.

Each remote step is a FIXED POSIX sh script; everything that comes from the
inventory or the fleet file reaches it only as a positional argument, quoted
with shlex.quote. No value is ever spliced into shell text, so a device path
or a project name cannot become code whatever it contains. Tests assert the
argv tuples built here; transport.py runs them.
"""
from __future__ import annotations

import json
import shlex
from dataclasses import dataclass

PROG = "rosdeploy"   # $0 of every script: shows up in `ps` on the robot


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


# The deploy guard's side of a run (see guard.py): arm it at the lock, re-arm it at each
# step with that step's deadline, disarm it at the run's end. `.claim` is the mutex between
# the controller and a guard taking over: once the guard holds it (acting), this run can
# neither re-arm nor activate any more.
_GUARD = r'''
g=$dir/.guard
guard_name=rosdeploy-guard-$project
claim() {
  i=0
  until mkdir "$g/.claim" 2>/dev/null; do
    [ ! -f "$g/acting" ] && [ $i -lt 20 ] || return 1
    i=$((i + 1)); sleep 0.1
  done
}
unclaim() { rmdir "$g/.claim" 2>/dev/null; }
armed_by() { [ -f "$g/state" ] && grep -qxF "run=$1" "$g/state"; }
took_over() { echo "the deploy guard on the robot took this run over (it acted at its deadline)" >&2; return 6; }
# rearm RUN PHASE SECONDS: a new deadline for this run's guard
rearm() {
  claim || { took_over; return 6; }
  if armed_by "$1"; then
    { cat "$g/state"; printf 'phase=%s\ndeadline=%s\n' "$2" "$(( $(date +%s) + $3 ))"; } > "$g/state.tmp" \
      && mv "$g/state.tmp" "$g/state"
    unclaim; return 0
  fi
  unclaim; took_over
}
# disarm RUN [strict]: the guard of this run goes (it removes its own container within a
# second); strict: fail if it is no longer armed (it acted: the run must not activate)
disarm() {
  [ -d "$g" ] || { [ -z "${2:-}" ] || took_over; return; }
  claim || { took_over; return 6; }
  if armed_by "$1"; then rm -f "$g/state"; unclaim; return 0; fi
  unclaim
  [ -z "${2:-}" ] || took_over
}
# start_guard IMAGE...: the guard's container, from the first image that has chroot; in the
# background of a step, so it costs that step no time. dockerd starts it again at boot.
start_guard() {
  # One start at a time: the first `up` may come while the lock's start still runs; it
  # waits for that one rather than replacing its container.
  i=0
  until mkdir "$g/.starting" 2>/dev/null; do
    [ $i -lt 100 ] || return 1
    i=$((i + 1)); sleep 0.1
  done
  [ ! -f "$g/container" ] || { rmdir "$g/.starting"; return 0; }
  started_guard "$@"; code=$?
  rmdir "$g/.starting"
  return $code
}
started_guard() {
  for img in "$@"; do
    for try in 1 2; do
      if docker run -d --pull never --name "$guard_name" --label "rosdeploy.guard=$project" --restart always \
           --network none --no-healthcheck --user 0:0 -e HOME="$HOME" -v /:/host --entrypoint chroot "$img" \
           --userspec="$(id -u):$(id -g)" --groups="$(id -G | tr ' ' ,)" \
           /host /bin/sh "$g/guard.sh" "$g" "$guard_name" >/dev/null 2>>"$g/log"; then
        printf '%s\n' "$guard_name" > "$g/container"; return 0
      fi
      docker rm -f "$guard_name" >/dev/null 2>&1     # one leaving, a stale one, or no chroot in $img
    done
  done
  echo "no image to run the deploy guard from: $*" >> "$g/log"; return 1
}
# arm STATE SECONDS FILE*6 IMAGE...: write the guard's files and state, start its container
arm() {
  text=$1; after=$2; shift 2
  mkdir -p "$g" || return 1
  for f in guard.sh up.sh finish.sh probe.sh ros_probe.py probe.json; do printf '%s\n' "$1" > "$g/$f"; shift; done
  claim || return 6
  boot=; read -r boot < /proc/sys/kernel/random/boot_id 2>/dev/null || true
  now=$(date +%s)
  { printf '%s' "$text"; printf 'dir=%s\nphase=prepare\narmed=%s\ndeadline=%s\nboot=%s\n' "$dir" "$now" "$((now + after))" "$boot"; } \
    > "$g/state.tmp" && mv "$g/state.tmp" "$g/state"
  unclaim
  # Detached from this step's output (dash keeps a redirected function call's pipe open)
  [ -f "$g/container" ] || ( exec </dev/null >/dev/null 2>&1; start_guard $(cat "$dir/current/images.txt" 2>/dev/null) "$@" ) &
}
'''

# Shared prologue: resolve "~/..." against the SSH user's home (the remote shell
# cannot expand a quoted "~"), and define the project directory.
_PROLOGUE = r'''
set -u
root=$1; project=$2; shift 2
case $root in "~") root=$HOME;; "~/"*) root=$HOME/${root#"~/"};; esac
dir=$root/$project
'''

# Compose command: v2 plugin or v1 binary, chosen by the caller after `state`.
_COMPOSE = r'''
compose() { if [ "$flavor" = v1 ]; then docker-compose "$@"; else docker compose "$@"; fi; }
'''

# The project's containers in one call. The Engine API through curl when the CLI would
# talk to the local socket anyway: ~12 ms of CPU less per call than the docker CLI (a Go
# program) on the benchmark's PC, and `status` runs it on every robot at once. Else one
# `docker ps` (contexts, remote DOCKER_HOST, no curl). parse_containers reads both.
_PS = r"""
ps_json() {
  sock=/var/run/docker.sock
  case ${DOCKER_HOST:-} in "") ;; unix://*) sock=${DOCKER_HOST#unix://} ;; *) sock= ;; esac
  if [ -n "$sock" ] && [ -S "$sock" ] && command -v curl >/dev/null 2>&1 \
     && ! contains "$HOME/.docker/config.json" '"currentContext"'; then
    filter="%7B%22label%22%3A%5B%22com.docker.compose.project%3D$project%22%5D%7D"   # project: [a-z0-9_-]
    if api=$(curl -sf --max-time 10 --unix-socket "$sock" "http://docker/containers/json?all=1&filters=$filter"); then
      printf '%s\n' "$api"
      return
    fi
  fi
  docker ps -a --filter "label=com.docker.compose.project=$project" --format '{"name":{{json .Names}},"service":{{json (.Label "com.docker.compose.service")}},"image":{{json .Image}},"status":{{json .State}},"ps_status":{{json .Status}},"workdir":{{json (.Label "com.docker.compose.project.working_dir")}},"compose":{{json (.Label "com.docker.compose.version")}},"hash":{{json (.Label "io.rosdeploy.hash")}}}' 2>/dev/null
}
"""

# Shell built-ins for the small files: each program started (cat, ls, grep) is a fork
# and an exec, and `status` runs this on every robot at once.
_FILES = r"""
show() { [ -r "$1" ] || return 0; while IFS= read -r line || [ -n "$line" ]; do printf '%s\n' "$line"; done < "$1"; }
contains() { case $(show "$1") in *"$2"*) return 0 ;; esac; return 1; }
"""

# The state's sections, for `mode` quick (no-op and status: files and containers), full
# (also the preflight facts) or switch (a rollback's: files and the kept releases'
# manifests; no container list, whose `docker ps` is a Go program's start on the robot).
_STATE_SECTIONS = _PS + r"""
section() { printf '\n@@%s\n' "$1"; }
section home; printf '%s\n' "$HOME"
section dir; printf '%s\n' "$dir"
section current; readlink "$dir/current" 2>/dev/null || true
section manifest; show "$dir/current/manifest.json"
section lock; show "$dir/.lock/owner"
section releases; for r in "$dir"/releases/*; do [ -e "$r" ] && printf '%s\n' "${r##*/}"; done
section history; tail -n 50 "$dir/history.jsonl" 2>/dev/null || true
section guard; show "$dir/.guard/state"
section guard-acting; show "$dir/.guard/acting"
# The robot's clock, for the guard's deadline: only when one is armed (a fork otherwise saved)
if [ -e "$dir/.guard/state" ] || [ -e "$dir/.guard/acting" ]; then section clock; date +%s; fi
section boot; show /proc/sys/kernel/random/boot_id
if [ "$mode" = switch ]; then
  for r in "$dir"/releases/*; do [ -r "$r/manifest.json" ] && { section "manifest ${r##*/}"; show "$r/manifest.json"; }; done
else
  section containers; ps_json
fi
if [ "$mode" = full ]; then
  section docker; docker version --format '{{.Server.Version}}' 2>&1 || true
  section compose
  if [ "$want_compose" != v1 ] && v=$(docker compose version --short 2>/dev/null); then printf 'v2 %s\n' "$v"
  elif v=$(docker-compose version --short 2>/dev/null); then printf 'v1 %s\n' "$v"
  fi
  section disk
  p=$root; while [ ! -d "$p" ]; do p=$(dirname "$p"); done
  df -Pk "$p" 2>/dev/null | awk 'NR==2 {print int($4/1024)}'
  section gpu
  if [ "$want_gpu" = yes ]; then docker info --format '{{json .Runtimes}}' 2>/dev/null; fi
  section devices
  for d in "$@"; do [ -e "$d" ] || printf 'missing %s\n' "$d"; done
fi
section end
"""

STATE_SCRIPT = _PROLOGUE + _FILES + r"""
mode=$1; want_compose=$2; want_gpu=$3; shift 3
""" + _STATE_SECTIONS


def state(root: str, project: str, devices: tuple[str, ...] = (), compose: str = "auto",
          gpu: bool = False, full: bool = True) -> Command:
    """What apply/plan/status need to know about a robot, in ONE round trip.

    Quick (full=False) is enough to tell a no-op and to show status; full adds the
    preflight facts (Docker and Compose versions, disk, devices, GPU runtime).
    """
    return script("state" if full else "state (quick)", STATE_SCRIPT, root, project,
                  "full" if full else "quick", compose, "yes" if gpu else "no", *devices)


# take_lock OWNER BREAK_STALE DEAD_RUN: prints `locked` (0) or `held <owner>` (3).
_LOCK = r'''
take_lock() {
  owner=$1; break_stale=$2; dead_run=${3:-}
  mkdir -p "$dir/releases" "$dir/logs" || { echo "cannot create $dir (owned by another user?)" >&2; return 1; }
  if [ "$break_stale" = yes ]; then rm -rf "$dir/.lock" "$dir/.lock-break"; fi
  if [ -n "$dead_run" ] && mkdir "$dir/.lock-break" 2>/dev/null; then
    # Remove the lock of a run the caller proved dead, and only that lock. .lock-break keeps
    # out a second run that found it dead too: that one then finds the lock held by us.
    if grep -qF "\"run\": \"$dead_run\"" "$dir/.lock/owner" 2>/dev/null; then rm -rf "$dir/.lock"; fi
    taken=no
    if mkdir "$dir/.lock" 2>/dev/null; then printf '%s\n' "$owner" > "$dir/.lock/owner"; taken=yes; fi
    rmdir "$dir/.lock-break"
    if [ $taken = yes ]; then echo locked; return 0; fi
  fi
  if mkdir "$dir/.lock" 2>/dev/null; then
    printf '%s\n' "$owner" > "$dir/.lock/owner"
    echo locked
  elif [ -d "$dir/.lock" ]; then
    printf 'held '; cat "$dir/.lock/owner" 2>/dev/null || echo '{}'
    return 3
  else
    echo "cannot create the lock $dir/.lock: check the deploy root's owner and permissions" >&2
    return 1
  fi
}
'''

LOCK_SCRIPT = _PROLOGUE + _LOCK + _GUARD + r'''
take_lock "$1" "$2" "$3" || exit $?
shift 3
[ $# -eq 0 ] && exit 0
arm "$@"; armed=$?
[ $armed = 0 ] && exit 0
rm -rf "$dir/.lock"
if [ $armed = 6 ]; then   # a guard is ending an interrupted run here: the robot is its until then
  printf 'held {"by": "the deploy guard (ending an interrupted run)", "run": "guard"}\n'
  exit 3
fi
echo "cannot arm the deploy guard in $dir/.guard: check the deploy root's owner and permissions" >&2
exit 1
'''

# A rollback's first round trip: the lock, then the state read under it (what it shows
# cannot change before the switch), with the kept releases' manifests.
LOCKED_STATE_SCRIPT = _PROLOGUE + _FILES + _LOCK + r'''
# Nothing deployed here: nothing to switch, so nothing to lock (and no directory to make).
if [ -d "$dir/releases" ]; then take_lock "$1" "$2" "$3"; locked=$?; else echo "nothing deployed"; locked=0; fi
mode=switch; shift 3
''' + _STATE_SECTIONS + r'''
exit $locked
'''

UNLOCK_SCRIPT = _PROLOGUE + _GUARD + r'''
token=$1
# The run ends: its guard goes with it, unless it took over (then the lock is its to release).
disarm "$token" || exit 0
# Only remove a lock we hold: another run may have broken ours and taken it.
if grep -qF "$token" "$dir/.lock/owner" 2>/dev/null; then rm -rf "$dir/.lock"; fi
'''


def lock(root: str, project: str, owner: dict, break_stale: bool = False, dead_run: str = "",
         guard: tuple[str, ...] = ()) -> Command:
    """mkdir is atomic on every filesystem: the lock is a directory holding its owner.
    `dead_run`: the run id of a holder proven dead; its lock (only) is removed first.
    `guard`: arm the deploy guard under the lock (see arm_args)."""
    return script("lock", LOCK_SCRIPT, root, project, json.dumps(owner, sort_keys=True),
                  "yes" if break_stale else "no", dead_run, *guard)


def arm_args(state: str, seconds: float, files: tuple[str, ...], images: tuple[str, ...]) -> tuple[str, ...]:
    """The lock's guard arguments: its state text, seconds to its first deadline, its six
    files (guard.sh, up.sh, finish.sh, probe.sh, ros_probe.py, probe.json), and the images
    its container may run from (the current release's are tried first)."""
    return (state, str(int(seconds)), *files, *images)


def locked_state(root: str, project: str, owner: dict, break_stale: bool = False, dead_run: str = "") -> Command:
    """`lock`, then the state as a rollback needs it (the lock's answer comes first, before
    the sections): one round trip where a rollback made three (state, lock, manifest)."""
    return script("lock+state", LOCKED_STATE_SCRIPT, root, project, json.dumps(owner, sort_keys=True),
                  "yes" if break_stale else "no", dead_run)


def unlock(root: str, project: str, token: str) -> Command:
    return script("unlock", UNLOCK_SCRIPT, root, project, token)


UPLOAD_SCRIPT = _PROLOGUE + _GUARD + r'''
release=$1; arm=$2; shift 2
# The pull is done: the guard's deadline now covers the steps up to the start.
[ -z "$arm" ] || rearm "${arm%% *}" prepare "${arm#* }" || exit 6
tmp=$dir/releases/.tmp-$release-$$
rm -rf "$tmp"; mkdir -p "$tmp"
tar -x -f - -C "$tmp" --no-same-owner || { rm -rf "$tmp"; echo "upload incomplete: tar failed" >&2; exit 5; }
chmod 0600 "$tmp/.env" 2>/dev/null || true
# A release with this id holds the same files by construction (the id is their digest):
# replace it whole so a half-written one from a cut connection never survives.
rm -rf "$dir/releases/$release"
mv "$tmp" "$dir/releases/$release"
# ROS log dirs survive releases. Created here, not by Docker (which would make them
# root-owned and unwritable for a non-root container user whose uid the robot does
# not know): sticky and world-writable, like /tmp.
for service in "$@"; do
  [ -d "$dir/logs/$service" ] || { mkdir -p "$dir/logs/$service" && chmod 1777 "$dir/logs/$service"; }
done
'''


def upload(root: str, project: str, release: str, tarball: bytes, services: tuple[str, ...] = (),
           rearm: str = "") -> Command:
    """Files go to a temporary dir and are renamed into place: never half-written.
    `rearm`: "RUN SECONDS", the guard's next deadline (see rearm)."""
    return script("upload", UPLOAD_SCRIPT, root, project, release, rearm, *services, stdin=tarball)


REARM_SCRIPT = _PROLOGUE + _GUARD + r'''
# A step that waits on the robot (the readiness gate) keeps the guard's deadline ahead of it.
rearm "${1%% *}" prepare "${1#* }" || exit 6
'''


def rearm(root: str, project: str, arm: str) -> Command:
    """Push this run's guard deadline out ("RUN SECONDS"); exit 6 when the guard already acted."""
    return script("rearm", REARM_SCRIPT, root, project, arm)


def rearm_arg(run: str, seconds: float) -> str:
    return f"{run} {int(seconds)}"


PULL_SCRIPT = r'''
set -u
# Pull what is missing, all images at once; keep going to report every failure.
fail=0; pids=""
for img in "$@"; do
  if ! docker image inspect "$img" >/dev/null 2>&1; then
    ( docker pull -q "$img" >/dev/null 2>/tmp/.rosdeploy-pull.$$.$(printf '%s' "$img" | cksum | cut -d' ' -f1) ) &
    pids="$pids $!"
  fi
done
for p in $pids; do wait "$p" || fail=1; done
for img in "$@"; do
  # range, not join: Docker 20.10's template sees RepoDigests as []interface{} and join fails
  id=$(docker image inspect --format '{{.Id}} {{range $i, $d := .RepoDigests}}{{if $i}},{{end}}{{$d}}{{end}}' "$img" 2>/dev/null)
  if [ -n "$id" ]; then printf 'ok %s %s\n' "$img" "$id"
  else
    f=/tmp/.rosdeploy-pull.$$.$(printf '%s' "$img" | cksum | cut -d' ' -f1)
    printf 'missing %s %s\n' "$img" "$(tr '\n' ' ' < "$f" 2>/dev/null)"
  fi
done
rm -f /tmp/.rosdeploy-pull.$$.*
exit $fail
'''


def pull(images: tuple[str, ...], timeout: float | None = None) -> Command:
    """Pull by versioned tag while the old release keeps running; present images are not pulled again."""
    return script("pull", PULL_SCRIPT, *images, timeout=timeout)


# What the health gate reads of a container: one line of JSON per container.
_INSPECT = r'''
fmt='{"id":{{json .Id}},"name":{{json .Name}},"service":{{json (index .Config.Labels "com.docker.compose.service")}},"image":{{json .Config.Image}},"status":{{json .State.Status}},"health":{{if .State.Health}}{{json .State.Health.Status}}{{else}}null{{end}},"restarts":{{.RestartCount}},"started":{{json .State.StartedAt}},"workdir":{{json (index .Config.Labels "com.docker.compose.project.working_dir")}},"test":{{if .Config.Healthcheck}}{{json .Config.Healthcheck.Test}},"test_timeout":{{json .Config.Healthcheck.Timeout}}{{else}}null{{end}}}'
'''

UP_SCRIPT = _PROLOGUE + _COMPOSE + _INSPECT + _GUARD + r'''
release=$1; flavor=$2; mode=$3; arm=$4; shift 4
cd "$dir/releases/$release" || { echo "release $release is not on this robot" >&2; exit 4; }
ids=
# Before the first container of the release starts: the guard's deadline becomes the
# gate's, and its container starts now if the lock could not start it (no image yet).
guard_pid=
if [ -n "$arm" ]; then
  rearm "${arm%% *}" start "${arm#* }" || exit 6
  if [ ! -f "$g/container" ]; then start_guard $(cat images.txt) </dev/null >/dev/null 2>&1 & guard_pid=$!; fi
fi
start() {
  case $mode in
    all) compose -p "$project" -f compose.yml up -d --remove-orphans 2>&1 ;;
    each)
      # One call per service: within one call compose would still wait for
      # `depends_on: service_healthy` between them; the caller checks dependencies itself.
      for service in "$@"; do
        compose -p "$project" -f compose.yml up -d --remove-orphans --no-deps "$service" 2>&1 || return $?
      done ;;
    together)
      # Stop what runs all at once (compose stops one service after another; `docker stop`
      # keeps each container's own stop signal and grace period), create everything, then
      # start it all at once, as dockerd does when the robot boots.
      running=$(docker ps -q --filter "label=com.docker.compose.project=$project")
      [ -z "$running" ] || docker stop $running >/dev/null || return $?
      compose -p "$project" -f compose.yml up --no-start --remove-orphans 2>&1 || return $?
      # One `docker start` per container, in parallel: one call starts them one by one.
      ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project" --filter status=created --filter status=exited)
      pids=
      for id in $ids; do docker start "$id" >/dev/null & pids="$pids $!"; done
      failed=0
      for pid in $pids; do wait "$pid" || failed=$?; done
      return $failed ;;
    *) echo "unknown start mode $mode" >&2; return 2 ;;
  esac
}
start "$@" || { code=$?; [ -z "$guard_pid" ] || wait "$guard_pid"; exit $code; }
[ -z "$guard_pid" ] || wait "$guard_pid"
# The project's containers as the gate's first poll would read them: that poll is one
# round trip (and, under load, a few tenths of a second) before the health watches begin.
printf '\n@@started\n'
[ -n "$ids" ] || ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project")
[ -z "$ids" ] || docker inspect --format "$fmt" $ids 2>/dev/null
exit 0
'''


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


# Runs inside the container: the health test again and again with no `docker exec` per
# try (an exec costs ~70 ms of robot CPU, the demo's test ~3 ms). A test that takes whole
# seconds (a `ros2` CLI call, say) is spaced by its own duration, so the loop keeps the
# robot at most half busy with it; a shorter one, slowed down by a busy CPU while the
# nodes start, is not (spacing it would delay the pass it is waiting for). Every try's
# time counts against the window.
# Exit 0: it passed; 3: still failing when the tries ran out; anything else: it cannot
# run this way (no /bin/sh in the image, or the container is gone).
HEALTH_WATCH_SCRIPT = r'''
tries=$1; every=$2; kind=$3; shift 3     # every: in hundredths of a second
# The clock in hundredths of a second, into $now. /proc/uptime is read by the shell itself
# (a `$(date)` is two processes, on every starting container while the nodes start).
# Whole seconds would not do: a 3 ms try that crosses a second's boundary would count
# as a 1 s one and wait a second more before the next try.
now() {
  if read -r now _ 2>/dev/null </proc/uptime; then
    cs=${now#*.}; now=$(( ${now%.*} * 100 + ${cs#0} ))
  else
    now=$(( $(date +%s 2>/dev/null || echo 0) * 100 ))
  fi
}
while :; do
  now; before=$now
  if [ "$kind" = CMD-SHELL ]; then /bin/sh -c "$1"; else "$@"; fi >/dev/null 2>&1 && exit 0
  now; took=$((now - before))
  if [ "$took" -ge 100 ]; then pause=$took; else pause=$every; fi
  tries=$((tries - (took + pause) / every))
  [ "$tries" -gt 0 ] || exit 3
  sleep "$((pause / 100)).$((pause / 10 % 10))$((pause % 10))"
done
'''


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


DOWN_SCRIPT = _PROLOGUE + _COMPOSE + r'''
release=$1; flavor=$2
cd "$dir/releases/$release" && compose -p "$project" -f compose.yml down --remove-orphans 2>&1
'''


def down(root: str, project: str, release: str, flavor: str) -> Command:
    return script("down", DOWN_SCRIPT, root, project, release, flavor)


CONTAINERS_SCRIPT = _INSPECT + r'''
project=$1; shift
if [ $# -gt 0 ]; then
  # Known containers by name: one docker CLI start per poll, not two (its whole cost on the
  # robot). A name that is gone is left out; the caller lists the project again then.
  docker inspect --format "$fmt" "$@" 2>/dev/null
else
  ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project" 2>/dev/null)
  [ -z "$ids" ] || docker inspect --format "$fmt" $ids 2>/dev/null
fi
exit 0
'''


def containers(project: str, names: tuple[str, ...] = ()) -> Command:
    """One line of JSON per container of the compose project (health gate poll);
    with `names`, only those containers, found without listing the project."""
    return script("containers", CONTAINERS_SCRIPT, project, *names)


def logs(container: str, lines: int = 20) -> Command:
    return Command(("docker", "logs", "--tail", str(lines), container), label=f"logs {container}")


ROS_PROBE_SCRIPT = r'''
c=$1; src=$2; arg=$3
exec docker exec "$c" sh -c 'for f in /opt/ros/*/setup.sh /ros_entrypoint_env.sh; do [ -f "$f" ] && . "$f" >/dev/null 2>&1; done; exec python3 -c "$0" "$1"' "$src" "$arg"
'''


def ros_probe(container: str, probe_source: str, spec: dict, timeout: float) -> Command:
    """Run rosdeploy's rclpy probe inside a running container of the release.

    ROS images need their setup sourced; images with rclpy on the default path
    (pip-installed ROS) work as they are.
    """
    return script("ros-probe", ROS_PROBE_SCRIPT, container, probe_source, json.dumps(spec, sort_keys=True),
                  timeout=timeout)


FINISH_SCRIPT = _PROLOGUE + _GUARD + r'''
release=$1; record=$2; keep=$3; run=${4:-}
cd "$dir" || exit 4
# The same step that switches `current` disarms the run's guard; if the guard took over
# already, this run must not switch.
[ -z "$run" ] || disarm "$run" strict || exit 6
ln -sfn "releases/$release" current.tmp && mv -T current.tmp current
# mtime = activation order, so pruning keeps the releases that last ran, not the last uploaded
touch "releases/$release"
printf '%s\n' "$record" >> history.jsonl
# Prune: keep the newest $keep releases by mtime, never the current one; then the
# images only pruned releases used (each release lists its images in images.txt).
old_imgs=""
for old in $(ls -1t releases | grep -v '^\.' | grep -vx "$release" | tail -n +"$keep"); do
  old_imgs="$old_imgs $(cat "releases/$old/images.txt" 2>/dev/null)"
  rm -rf "releases/$old"; printf 'pruned %s\n' "$old"
done
kept=$(cat releases/*/images.txt 2>/dev/null | sort -u)
for img in $old_imgs; do
  printf '%s\n' "$kept" | grep -qxF "$img" || { docker image rm "$img" >/dev/null 2>&1 && printf 'removed %s\n' "$img"; }
done
exit 0
'''


def finish(root: str, project: str, release: str, record: dict, keep: int, guard_run: str = "") -> Command:
    """Point `current` at the release (atomic rename), append history, prune old releases.
    `guard_run`: disarm this run's guard first (exit 6 if it took over)."""
    return script("activate", FINISH_SCRIPT, root, project, release,
                  json.dumps(record, sort_keys=True), str(keep), guard_run)


RECORD_SCRIPT = _PROLOGUE + _GUARD + r'''
mkdir -p "$dir" && printf '%s\n' "$1" >> "$dir/history.jsonl" || exit $?
[ -z "${2:-}" ] || rearm "${2%% *}" start "${2#* }"
'''


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


MANIFEST_SCRIPT = _PROLOGUE + _FILES + r'''
show "$dir/releases/$1/manifest.json"
'''


def manifest(root: str, project: str, release: str) -> Command:
    """A kept release's manifest.json (empty output when it has none)."""
    return script("manifest", MANIFEST_SCRIPT, root, project, release)


RELEASE_FILES_SCRIPT = _PROLOGUE + r'''
release=$1; shift
n=0
for name in "$@"; do
  n=$((n + 1))
  printf '\n@@file%s\n' "$n"; cat "$dir/releases/$release/$name" 2>/dev/null || printf '!!absent!!'
done
printf '\n@@images\n'
while read -r img; do
  [ -n "$img" ] && { docker image inspect "$img" >/dev/null 2>&1 && echo "present $img" || echo "missing $img"; }
done
printf '\n@@end\n'
'''


def release_files(root: str, project: str, release: str, names: tuple[str, ...], images: tuple[str, ...]) -> Command:
    """The files of a kept release (for plan's diff) and which of `images` the robot lacks.

    Images travel on stdin, one per line, so the argv stays one list of file names.
    """
    return script("read-release", RELEASE_FILES_SCRIPT, root, project, release, *names,
                  stdin="".join(f"{i}\n" for i in images).encode())
