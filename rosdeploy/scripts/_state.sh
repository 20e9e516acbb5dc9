# shellcheck shell=sh source-path=SCRIPTDIR
# The state's sections, for `mode` quick (no-op and status: files and containers), full
# (also the preflight facts) or switch (a rollback's: files and the kept releases'
# manifests; no container list, whose `docker ps` is a Go program's start on the robot).
. ./_prologue.sh
. ./_files.sh
. ./_ps.sh

section() { printf '\n@@%s\n' "$1"; }
section home; printf '%s\n' "$HOME"
section dir; printf '%s\n' "$dir"
section current; readlink "$dir/current" 2>/dev/null || true
section manifest; show "$dir/current/manifest.json"
section lock; show_head "$dir/.lock/owner" 4096
# held with no readable owner (a controller killed between its mkdir and the owner's write)
section lockdir; if [ -d "$dir/.lock" ]; then echo yes; fi
kept=
section releases; for r in "$dir"/releases/*; do [ -e "$r" ] && printf '%s\n' "${r##*/}" && kept="$kept ${r##*/}"; done
# The last 50 lines; then, under `gates`, the older lines that still decide a rollback: each
# kept release's last activation and the last rollback away from it (a run of failed deploys
# must not push the release to go back to out of sight, nor may the whole file be sent).
section history
[ ! -f "$dir/history.jsonl" ] || awk -v n=50 -v kept="$kept" '
  BEGIN { k = split(kept, ks, " ") }
  { b[NR % n] = $0
    for (i = 1; i <= k; i++) {
      q = "\"" ks[i] "\""
      if (index($0, "\"release\": " q) && index($0, "\"result\": \"active\"")) { a[i] = NR; at[i] = $0 }
      if (index($0, "\"rolled_back_from\": " q)) { f[i] = NR; ft[i] = $0 }
    } }
  END {
    first = NR > n ? NR - n + 1 : 1
    for (i = first; i <= NR; i++) print b[i % n]
    printf "\n@@gates\n"
    for (i = 1; i <= k; i++) { if (a[i] && a[i] < first) o[a[i]] = at[i]; if (f[i] && f[i] < first) o[f[i]] = ft[i] }
    for (i = 1; i < first; i++) if (i in o) print o[i]
  }' "$dir/history.jsonl" 2>/dev/null || true
section guard; show "$dir/.guard/state"
section guard-acting; show "$dir/.guard/acting"
# The robot's clock, for the guard's deadline: only when one is armed (a fork otherwise saved)
# and whether its container is there: a guard that state promises but dockerd does not run
# cannot act, and status must not say it will
if [ -e "$dir/.guard/state" ] || [ -e "$dir/.guard/acting" ]; then
  section clock; date +%s
  section guard-container; docker inspect -f '{{.State.Status}}' "rosdeploy-guard-$project" 2>/dev/null || echo none
fi
section boot; show /proc/sys/kernel/random/boot_id
# shellcheck disable=SC2154 # mode: set by the script (state.sh, locked-state.sh)
if [ "$mode" = switch ]; then
  for r in "$dir"/releases/*; do
    [ -r "$r/manifest.json" ] && { section "manifest ${r##*/}"; show "$r/manifest.json"; }
  done
else
  section containers; ps_json
fi
# shellcheck disable=SC2154 # mode, want_compose, want_gpu: set by the script (state.sh)
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
# The host changes installed (hostchanges.py): a no-op apply puts back what differs from its release.
if [ "$mode" != switch ]; then
  section hostfiles
  for f in "/etc/udev/rules.d/99-rosdeploy-$project.rules" "/etc/logrotate.d/rosdeploy-$project" \
           "/etc/cron.d/rosdeploy-$project"; do
    if [ -r "$f" ]; then sha256sum < "$f" | { read -r sum _; printf '%s %s\n' "$sum" "$f"; }
    elif [ -e "$f" ]; then printf '? %s\n' "$f"; fi
  done
fi
section end
