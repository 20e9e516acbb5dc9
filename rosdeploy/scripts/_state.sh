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
section lock; show "$dir/.lock/owner"
section releases; for r in "$dir"/releases/*; do [ -e "$r" ] && printf '%s\n' "${r##*/}"; done
section history; tail -n 50 "$dir/history.jsonl" 2>/dev/null || true
section guard; show "$dir/.guard/state"
section guard-acting; show "$dir/.guard/acting"
# The robot's clock, for the guard's deadline: only when one is armed (a fork otherwise saved)
if [ -e "$dir/.guard/state" ] || [ -e "$dir/.guard/acting" ]; then section clock; date +%s; fi
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
