# shellcheck shell=sh
# Runs inside the container: the health test again and again with no `docker exec` per
# try (an exec costs ~70 ms of robot CPU, the demo's test ~3 ms). A test that takes whole
# seconds (a `ros2` CLI call, say) is spaced by its own duration, so the loop keeps the
# robot at most half busy with it; a shorter one, slowed down by a busy CPU while the
# nodes start, is not (spacing it would delay the pass it is waiting for). Every try's
# time counts against the window.
# Exit 0: it passed; 3: still failing when the tries ran out; anything else: it cannot
# run this way (no /bin/sh in the image, or the container is gone).

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
