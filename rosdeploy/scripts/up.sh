# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_compose.sh
. ./_inspect.sh
. ./_guard.sh
. ./_files.sh

release=$1; flavor=$2; mode=$3; arm=$4; shift 4
cd "$dir/releases/$release" || { echo "release $release is not on this robot" >&2; exit 4; }
ids=
# Before the first container of the release starts: the guard's deadline becomes the
# gate's, and its container starts now if the lock could not start it (no image yet).
guard_pid=
if [ -n "$arm" ]; then
  rearm "${arm%% *}" start "${arm#* }" || exit 6
  # shellcheck disable=SC2046 # one image a word: images.txt is rosdeploy's, one name a line
  start_guard $(cat images.txt) </dev/null >/dev/null 2>&1 & guard_pid=$!
fi
# said FILE: what the brake's docker calls said, once it is done (then the file goes)
said() { show "$1"; rm -f "$1"; }
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
      # The brake goes back to a release that passed its gate: once it stopped what ran, it
      # finishes even if the controller or its link dies meanwhile. Nothing writes to the
      # channel before every container was started (a write to a closed one killed the
      # script, and the robot ran nothing until the guard's deadline, minutes later).
      trap '' HUP PIPE
      said=$(mktemp) || return $?
      running=$(docker ps -q --filter "label=com.docker.compose.project=$project")
      # shellcheck disable=SC2086 # container ids, one a word
      [ -z "$running" ] || docker stop $running >/dev/null 2>"$said" || { code=$?; said "$said"; return $code; }
      compose -p "$project" -f compose.yml up --no-start --remove-orphans >"$said" 2>&1 || \
        { code=$?; said "$said"; return $code; }
      # One `docker start` per container, in parallel: one call starts them one by one.
      ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project" \
        --filter status=created --filter status=exited)
      pids=
      for id in $ids; do docker start "$id" >/dev/null 2>>"$said" & pids="$pids $!"; done
      failed=0
      for pid in $pids; do wait "$pid" || failed=$?; done
      said "$said"
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
# shellcheck disable=SC2086 # container ids, one a word
[ -z "$ids" ] || docker inspect --format "$fmt" $ids 2>/dev/null
exit 0
