# shellcheck shell=sh
# Host changes, as root (hostchanges.py): install the release's udev rules and log rotation
# where they differ, remove them where the release has none. Notes go to stdout, one a line.
# $1 release dir  $2 rules target  $3 logrotate.d target  $4 cron.d target  $5 state dir
# $6 subsystems to trigger (comma-separated)
set -u
rel=$1; rules=$2; conf=$3; cron=$4; state=$5; subsystems=$6
content() { grep -qv '^[[:space:]]*\(#.*\)\{0,1\}$' "$1" 2>/dev/null; }
# place SRC TARGET: install SRC as TARGET (0644, root, by rename), or remove TARGET when SRC has
# no content. Status 0: changed, 1: already so.
place() {
  if ! content "$1"; then
    [ -e "$2" ] || return 1
    rm -f "$2" && echo "removed $2" && return 0
    exit 5
  fi
  if [ -f "$2" ] && cmp -s "$1" "$2"; then return 1; fi
  mkdir -p "${2%/*}" && cp "$1" "$2.tmp" && chmod 0644 "$2.tmp" && mv "$2.tmp" "$2" || exit 5
  echo "installed $2"
}

# ---- log rotation: the config first, so that the schedule never runs without it
rotation=$rel/logrotate.cron
if content "$rotation"; then
  logrotate=$(command -v logrotate || echo /usr/sbin/logrotate)
  if ! out=$("$logrotate" -d -s /dev/null "$rel/logrotate.conf" 2>&1); then
    echo "logrotate refused the rotation config: $(printf '%s' "$out" | grep -i error | head -3 | tr '\n' ' ')"
    exit 6
  fi
  mkdir -p "$state"
  place "$rel/logrotate.conf" "$conf" || :
  place "$rotation" "$cron" || :
else
  place "$rotation" "$cron" || :      # the schedule first: it must not run without its config
  place "$rotation" "$conf" || :
fi

# ---- udev rules
place "$rel/99-rosdeploy.rules" "$rules"; changed=$?
[ -f "$rules" ] || [ $changed = 0 ] || exit 0
if command -v udevadm >/dev/null 2>&1; then
  if [ -f "$rules" ] && udevadm verify --help >/dev/null 2>&1; then
    if udevadm verify "$rules" >/dev/null 2>&1; then echo "udevadm verify: ok"; else echo "udevadm verify failed"; exit 6; fi
  fi
  if [ ! -S /run/udev/control ]; then
    echo "note: udevd is not running here; rules installed, not loaded"
  elif [ $changed = 0 ]; then
    set --
    for s in $(echo "$subsystems" | tr ',' ' '); do set -- "$@" "--subsystem-match=$s"; done
    if udevadm control --reload-rules && udevadm trigger --action=change "$@" && udevadm settle -t 10; then
      echo "udev rules reloaded"
    else echo "udev reload failed"; fi
  fi
else
  echo "note: no udev on this robot (a container?); rules installed, not loaded"
fi
