#!/bin/sh
# The deploy guard (see rosdeploy/guard.py and docs/guard.md). $1: its directory
# ($dir/.guard), $2: its container's name. Runs as the deploying user (chroot --userspec)
# with the robot's own sh, docker and compose.
set -u
g=$1; name=$2
PATH=${PATH:-/usr/bin:/bin}:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin; export PATH
say() { printf '%s %s\n' "$(date -u +%Y-%m-%dT%H:%M:%SZ)" "$*" >> "$g/log" 2>/dev/null; }
# get KEY FILE: the last value of KEY (read by the shell itself: this runs every second)
get() {
  v=
  while IFS= read -r line || [ -n "$line" ]; do case $line in "$1="*) v=${line#*=} ;; esac; done < "$2" 2>/dev/null
  printf '%s' "$v"
}
leave() {
  rm -f "$g/container"
  # A new run armed just now and found this container: it stays and guards that run.
  if [ -f "$g/state" ]; then printf '%s\n' "$name" > "$g/container"; return 1; fi
  say "guard of run ${run:-?} leaves"
  docker update --restart=no "$name" >/dev/null 2>&1
  docker rm -f "$name" >/dev/null 2>&1     # ends this script: the last thing it does
  exit 0
}
compose() { if [ "$flavor" = v1 ]; then docker-compose "$@"; else docker compose "$@"; fi; }
clean() { printf '%s' "$1" | tr -d '"\\\000-\037'; }

# check RELEASE [SERVICE...]: 0 all of the project's containers run RELEASE, running and
# healthy (or without a check); 1 not yet; 2 broken (exited, restarting, unhealthy). $why, $sum.
check() {
  rel=$1; shift; why=; sum=0; seen=" "; code=0
  ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project")
  out=
  fmt='{{.State.Status}} {{if .State.Health}}{{.State.Health.Status}}{{else}}none{{end}} {{.RestartCount}}'
  fmt="$fmt"' {{index .Config.Labels "com.docker.compose.service"}}'
  fmt="$fmt"' {{index .Config.Labels "com.docker.compose.project.working_dir"}}'
  # shellcheck disable=SC2086  # container ids, one argument each
  [ -z "$ids" ] || out=$(docker inspect --format "$fmt" $ids 2>/dev/null)
  while read -r st hl rc svc wd; do
    [ -n "${svc:-}" ] || continue
    sum=$((sum + rc)); seen="$seen$svc "
    case $wd in */releases/"$rel") ;; *) [ $code -ge 1 ] || { why="$svc runs another release"; code=1; }; continue ;; esac
    case $st in
      running) ;;
      exited|dead|restarting) why="$svc: container $st"; code=2; continue ;;
      *) [ $code -ge 1 ] || { why="$svc: container $st"; code=1; }; continue ;;
    esac
    case $hl in
      unhealthy) why="$svc: health check reports unhealthy"; code=2 ;;
      starting) [ $code -ge 1 ] || { why="$svc: health starting"; code=1; } ;;
    esac
  done <<EOF
$out
EOF
  [ -n "$ids" ] || { why="no container"; code=1; }
  for s in "$@"; do case $seen in *" $s "*) ;; *) [ $code -ge 1 ] || { why="$s: no container"; code=1; } ;; esac; done
  return $code
}

# wait_ok RELEASE SECONDS [SERVICE...]: until check says 0 (then 0), 2, or the time is up
wait_ok() {
  rel=$1; end=$(( $(date +%s) + $2 )); shift 2
  while :; do
    check "$rel" "$@"; c=$?
    [ $c = 1 ] || return $c
    [ "$(date +%s)" -lt "$end" ] || { why="${why:-not healthy} after ${gate}s (health.timeout)"; return 1; }
    sleep 1
  done
}

# The release's own gate, as the controller runs it: running, healthy, no restart over
# health.stable, then the ROS graph probe inside a container of the release.
gate_ok() {
  sh "$g/up.sh" "$root" "$project" "$target" "$flavor" all "" >> "$g/log" 2>&1
  # shellcheck disable=SC2086  # service names (the fleet file's [a-z0-9_-]), one argument each
  wait_ok "$target" "$gate" $services || return 1
  before=$sum
  sleep "$stable"
  # shellcheck disable=SC2086  # as above
  check "$target" $services || return 1
  [ "$sum" = "$before" ] || { why="a container restarted within health.stable (${stable}s)"; return 1; }
  [ -n "$probe" ] || return 0
  c=$(docker ps -q --filter "label=com.docker.compose.project=$project" --filter "label=com.docker.compose.service=$probe" | head -n 1)
  [ -n "$c" ] || { why="no running $probe container to probe the ROS graph from"; return 1; }
  probe_graph "$c" && return 0
  # Once more, with a fresh participant: on a loaded robot one probe's discovery can miss a
  # publisher that is there (seen once in CI), and a false verdict here undoes a good release.
  say "$why; probing once more"
  sleep 1
  probe_graph "$c"
}
probe_graph() {
  out=$(sh "$g/probe.sh" "$1" "$(cat "$g/ros_probe.py")" "$(cat "$g/probe.json")" 2>&1) && return 0
  why="ROS graph probe failed: $(printf '%s' "$out" | tail -n 1 | cut -c1-300)"
  return 1
}

# entry EVENT RELEASE RESULT REASON [ROLLED_BACK_FROM]: one history line
entry() {
  rel=null; [ -z "$2" ] || rel="\"$2\""
  back=; [ -z "${5:-}" ] || back=", \"rolled_back_from\": \"$5\""
  printf '{"by": "guard (run %s by %s)", "compose": "%s", "event": "%s", "from": "%s", "reason": "%s", "release": %s, "result": "%s"%s, "run": "%s", "time": "%s"}\n' \
    "$run" "$(clean "$by")" "$flavor" "$1" "$previous" "$(clean "$4")" "$rel" "$3" "$back" "$run" "$(date -u +%Y-%m-%dT%H:%M:%S+00:00)"
}
# record ENTRY-ARGS...: the entry as a line of its own in the history, also after a last
# line a power loss cut short (as scripts/_files.sh's append)
record() {
  f=$dir/history.jsonl
  [ ! -s "$f" ] || [ -z "$(tail -c 1 "$f")" ] || printf '\n' >> "$f"
  entry "$@" >> "$f"
}

# host_back RELEASE: its udev rules and log rotation again (rosdeploy/scripts/hostchanges-restore.sh,
# which the controller's host-changes step left in $dir/.host/)
host_back() {
  [ ! -f "$dir/.host/restore.sh" ] || sh "$dir/.host/restore.sh" "$dir" "$1" >> "$g/log" 2>&1 \
    || say "host changes of $1 not restored (see above)"
}

revert() {
  if [ -n "$previous" ] && [ -d "$dir/releases/$previous" ]; then
    say "starting $previous again ($1)"
    sh "$g/up.sh" "$root" "$project" "$previous" "$flavor" together "" >> "$g/log" 2>&1
    host_back "$previous"
    if wait_ok "$previous" "$gate"; then result=active; else result=unhealthy; fi
    record guard-rollback "$previous" "$result" "$1" "$target"
  else
    say "no activated release to go back to: stopping $target ($1)"
    (cd "$dir/releases/$target" && compose -p "$project" -f compose.yml down --remove-orphans) >> "$g/log" 2>&1
    record guard-rollback "" stopped "$1; no activated release to go back to, so $target was stopped" "$target"
  fi
}

# runs_on RELEASE [SERVICE...]: every container of the project is running and from RELEASE,
# and every SERVICE has one (their health aside: wait_ok judges that)
runs_on() {
  rel=$1; shift; seen=" "
  ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project")
  [ -n "$ids" ] || return 1
  fmt='{{.State.Status}} {{index .Config.Labels "com.docker.compose.service"}}'
  fmt="$fmt"' {{index .Config.Labels "com.docker.compose.project.working_dir"}}'
  # shellcheck disable=SC2086  # container ids, one argument each
  out=$(docker inspect --format "$fmt" $ids 2>/dev/null) || return 1
  while read -r st svc wd; do
    [ -n "${svc:-}" ] || continue
    [ "$st" = running ] || return 1
    case $wd in */releases/"$rel") seen="$seen$svc " ;; *) return 1 ;; esac
  done <<EOF
$out
EOF
  for s in "$@"; do case $seen in *" $s "*) ;; *) return 1 ;; esac; done
}

# An operator's rollback whose controller went away mid-switch: complete it as the brake
# does (the target passed its gate when it was activated before): start it all at once
# unless it runs already, activate it, one history line. A target that never passed a gate
# here is not left running: the release it left (`current`, activated) comes back instead.
finish_rollback() {
  if [ "$gated" != yes ]; then
    revert "$1; the rollback's target $target never passed its gate here"
    return
  fi
  say "finishing the rollback to $target ($1)"
  # shellcheck disable=SC2086  # service names (the fleet file's [a-z0-9_-]), one argument each
  runs_on "$target" $services || sh "$g/up.sh" "$root" "$project" "$target" "$flavor" together "" >> "$g/log" 2>&1
  host_back "$target"     # as the controller's rollback does right after its switch
  # shellcheck disable=SC2086  # as above
  if wait_ok "$target" "$gate" $services; then result=active; else result=unhealthy; fi
  sh "$g/finish.sh" "$root" "$project" "$target" \
    "$(entry guard-finished-rollback "$target" "$result" "$1" "$previous")" "$keep" "" >> "$g/log" 2>&1
}

act() {
  f=$g/acting
  dir=$(get dir "$f"); project=$(get project "$f"); target=$(get target "$f"); previous=$(get previous "$f")
  flavor=$(get flavor "$f"); mode=$(get mode "$f"); phase=$(get phase "$f"); services=$(get services "$f")
  gate=$(get gate "$f"); stable=$(get stable "$f"); keep=$(get keep "$f"); probe=$(get probe "$f")
  by=$(get by "$f"); reason=$(get reason "$f"); gated=$(get gated "$f")
  root=${dir%/*}
  say "acting on run $run: $reason (mode $mode, phase $phase)"
  if [ "$phase" = prepare ] && [ "$mode" = rollback ]; then
    previous=$(readlink "$dir/current" 2>/dev/null); previous=${previous##*/}
    record guard-rollback "$previous" unchanged "$reason before the rollback switched anything: nothing changed"
  elif [ "$mode" = rollback ]; then
    finish_rollback "$reason"
  elif [ "$phase" = prepare ]; then
    host_back "$previous"     # installed after the upload, before anything started
    record guard-rollback "$previous" unchanged "$reason before $target started: nothing changed"
  elif [ "$mode" = finish ]; then
    if gate_ok; then
      say "gate passed: activating $target"
      sh "$g/finish.sh" "$root" "$project" "$target" \
        "$(entry guard-finish "$target" active "$reason; the guard ran the gate and it passed")" "$keep" "" >> "$g/log" 2>&1
    else
      say "gate failed: $why"
      revert "$reason; the guard ran the gate and it failed: $why"
    fi
  else
    revert "$reason"
  fi
  # The lock of the run that armed us, and only that one.
  if grep -qF "\"run\": \"$run\"" "$dir/.lock/owner" 2>/dev/null; then rm -rf "$dir/.lock"; fi
  rm -f "$g/acting" "$g/started"
  rmdir "$g/.claim" 2>/dev/null
  leave
}

# claim REASON: take the state over (the controller cannot disarm or re-arm any more)
claim() {
  mkdir "$g/.claim" 2>/dev/null || return 1
  if [ "$(get run "$g/state")" = "$run" ]; then
    { cat "$g/state"; printf 'reason=%s\nacted=%s\n' "$1" "$(date +%s)"; } > "$g/acting.tmp" \
      && mv "$g/acting.tmp" "$g/acting" && rm -f "$g/state" && return 0
  fi
  rmdir "$g/.claim"
  return 1
}

if [ -f "$g/acting" ]; then
  run=$(get run "$g/acting")
  say "started again while acting: acting again"
  act
fi
[ -f "$g/state" ] || leave
# A start that replaced a leaving guard may have lost its `container` file to that guard's leave
printf '%s\n' "$name" > "$g/container"
run=$(get run "$g/state" 2>/dev/null)
boot=$(cat /proc/sys/kernel/random/boot_id 2>/dev/null)
restarted=no
[ "$(get boot "$g/state")" = "$boot" ] || restarted=yes
# dockerd started this same container again (same run, same container: its hostname):
# the robot (or its engine) restarted since it was armed
read -r me < /proc/sys/kernel/hostname 2>/dev/null || me=
[ "$(cat "$g/started" 2>/dev/null)" != "$run $me" ] || restarted=yes
printf '%s %s\n' "$run" "$me" > "$g/started"
say "guard of run $run armed"
if [ $restarted = yes ]; then
  what=deploy; [ "$(get mode "$g/state")" != rollback ] || what=rollback
  claim "robot restarted mid-$what" && act
fi
while :; do
  [ -f "$g/state" ] || { [ -f "$g/acting" ] && act; leave; continue; }
  run=$(get run "$g/state")     # a later run may have armed this same container
  deadline=$(get deadline "$g/state")
  if [ "$(date +%s)" -ge "${deadline:-0}" ]; then
    dir=$(get dir "$g/state")
    if grep -qF "\"run\": \"$run\"" "$dir/.lock/owner" 2>/dev/null; then why="controller lost"; else why="deadline"; fi
    claim "$why" && act
  fi
  sleep 1
done
