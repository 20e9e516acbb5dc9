# shellcheck shell=sh source-path=SCRIPTDIR
# The deploy guard's side of a run (see guard.py): arm it at the lock, re-arm it at each
# step with that step's deadline, disarm it at the run's end. `.claim` is the mutex between
# the controller and a guard taking over: once the guard holds it (acting), this run can
# neither re-arm nor activate any more.
. ./_prologue.sh

g=$dir/.guard
guard_name=rosdeploy-guard-$project
nl='
'
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
# rearm RUN PHASE SECONDS[\nKEY=VALUE...]: a new deadline for this run's guard; a rollback's
# lines after the first (target, flavor...: known only once its state was read) join the state
rearm() {
  claim || { took_over; return 6; }
  secs=${3%%"$nl"*}; more=${3#"$secs"}; more=${more#"$nl"}
  if armed_by "$1"; then
    { cat "$g/state"; printf 'phase=%s\ndeadline=%s\n%s' "$2" "$(( $(date +%s) + secs ))" "$more"; } > "$g/state.tmp" \
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
    # 10 s: no start takes that long; one left by a robot that restarted mid-start would bar every run
    [ $i -lt 100 ] || { rmdir "$g/.starting" 2>/dev/null; i=0; continue; }
    i=$((i + 1)); sleep 0.1
  done
  # `container`: a guard is starting or stays (guard.sh's leave removes it before it looks
  # for a new run's state). Checked against dockerd: a guard removed by hand, or one that left
  # in a way nothing saw, must not keep every later run unguarded.
  if [ -f "$g/container" ]; then
    if docker inspect "$guard_name" >/dev/null 2>&1; then rmdir "$g/.starting"; return 0; fi
    rm -f "$g/container"
  fi
  started_guard "$@"; code=$?
  rmdir "$g/.starting"
  return $code
}
started_guard() {
  for img in "$@"; do
    tries=0
    while :; do
      # Written before the start, never after: a guard with no run to guard leaves at once,
      # and its leave must find (and remove) this file, not be followed by it.
      printf '%s\n' "$guard_name" > "$g/container"
      if docker run -d --pull never --name "$guard_name" --label "rosdeploy.guard=$project" --restart always \
           --network none --no-healthcheck --user 0:0 -e HOME="$HOME" -v /:/host --entrypoint chroot "$img" \
           --userspec="$(id -u):$(id -g)" --groups="$(id -G | tr ' ' ,)" \
           /host /bin/sh "$g/guard.sh" "$g" "$guard_name" >/dev/null 2>>"$g/log"; then
        return 0
      fi
      docker rm -f "$guard_name" >/dev/null 2>&1     # one leaving, a stale one, or no chroot in $img
      tries=$((tries + 1))
      # A guard that is leaving (its run just disarmed it) holds the name until dockerd has
      # removed it: wait for that, up to ~5 s. Otherwise one more try, then the next image.
      if docker inspect "$guard_name" >/dev/null 2>&1; then
        [ $tries -lt 10 ] || break
        sleep 0.5
      else
        [ $tries -lt 2 ] || break
      fi
    done
  done
  rm -f "$g/container"
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
  { printf '%s' "$text"; printf 'dir=%s\nphase=prepare\narmed=%s\ndeadline=%s\nboot=%s\n' \
      "$dir" "$now" "$((now + after))" "$boot"; } \
    > "$g/state.tmp" && mv "$g/state.tmp" "$g/state"
  unclaim
  # Detached from this step's output (dash keeps a redirected function call's pipe open)
  # shellcheck disable=SC2046 # one image a word: images.txt is rosdeploy's, one name a line
  ( exec </dev/null >/dev/null 2>&1
    start_guard $(cat "$dir/current/images.txt" 2>/dev/null) "$@" ) &
}
