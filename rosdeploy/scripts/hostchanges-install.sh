# shellcheck shell=sh source-path=SCRIPTDIR
# Host changes, install (hostchanges.py): run as the SSH user. Decides from the release's files
# whether anything differs from what is installed (no root needed when nothing does), becomes
# root for hostchanges-root.sh when something does, then checks, as this user, that every
# mapped device resolves (after the udev trigger, before anything restarts).
# $1 release  $2 direct|sudo-n|sudo-S  $3 the root script  $4 subsystems (comma-separated)
# $5 rules target  $6 logrotate.d target  $7 cron.d target  $8 state dir  $9 the guard's restore
# script  $10... device paths
. ./_prologue.sh
release=$1; mode=$2; inner=$3; subsystems=$4; rules=$5; conf=$6; cron=$7; state=$8; restore=$9; shift 9
rel=$dir/releases/$release
[ -d "$rel" ] || { echo "release $release is not on this robot" >&2; exit 4; }
# A file with only comments and blank lines installs nothing (and removes what is there).
content() { grep -qv '^[[:space:]]*\(#.*\)\{0,1\}$' "$1" 2>/dev/null; }
# differs SRC TARGET: the release wants TARGET other than it is (SRC without content: absent)
differs() {
  if content "$1"; then ! cmp -s "$1" "$2"; else [ -e "$2" ]; fi
}
rotation=$rel/logrotate.cron
if content "$rotation"; then rotate_conf=$rel/logrotate.conf; else rotate_conf=$rotation; fi
if differs "$rel/99-rosdeploy.rules" "$rules" || differs "$rotation" "$cron" || differs "$rotate_conf" "$conf"; then
  set -- "$rel" "$rules" "$conf" "$cron" "$state" "$subsystems" -- "$@"
  case $mode in
    direct) sh -c "$inner" rosdeploy "$@" ;;
    sudo-n) sudo -n sh -c "$inner" rosdeploy "$@" ;;
    sudo-S) sudo -S -p '' sh -c "$inner" rosdeploy "$@" ;;
    *) echo "host changes differ, and root is not reachable ($mode)" >&2; exit 3 ;;
  esac || exit $?
  while [ "$1" != -- ]; do shift; done; shift
else
  echo "host changes unchanged"
fi
# What the deploy guard needs to restore a release's host changes without the controller.
mkdir -p "$dir/.host" && printf '%s\n' "$inner" > "$dir/.host/root.sh" && printf '%s\n' "$restore" > "$dir/.host/restore.sh" \
  && printf '%s\n' "$mode" "$subsystems" "$rules" "$conf" "$cron" "$state" > "$dir/.host/args" \
  || echo "note: cannot write $dir/.host: the deploy guard could not restore these host changes"
missing=0
for device in "$@"; do
  [ -e "$device" ] && continue
  echo "missing-device $device"; missing=1
done
[ $missing = 0 ] || exit 7
[ $# = 0 ] || echo "devices resolve: $*"
