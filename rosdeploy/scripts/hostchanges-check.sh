# shellcheck shell=sh source-path=SCRIPTDIR
# Host changes, preflight (hostchanges.py): run as the SSH user, changes nothing.
# $1: how root is reached (direct | sudo-n | sudo-S); then pairs TARGET SHA256 (`-`: the release
# installs no such file). Prints `differs TARGET` per file that differs from what the release
# wants, then, only when one does, `root ok|not-root|no-sudo|denied WHY`; and the tools.
. ./_prologue.sh
mode=$1; shift
need=no
while [ $# -ge 2 ]; do
  target=$1; want=$2; shift 2
  if [ "$want" = - ]; then
    [ -e "$target" ] || continue
  elif [ -f "$target" ] && [ "$(sha256sum < "$target" | cut -d' ' -f1)" = "$want" ]; then
    continue
  fi
  echo "differs $target"; need=yes
done
if [ $need = yes ]; then
  case $mode in
    direct) if [ "$(id -u)" = 0 ]; then echo "root ok"; else echo "root not-root"; fi ;;
    sudo-n|sudo-S)
      if ! command -v sudo >/dev/null 2>&1; then echo "root no-sudo"
      elif [ "$mode" = sudo-n ] && err=$(sudo -n true 2>&1); then echo "root ok"
      elif [ "$mode" = sudo-S ] && err=$(sudo -S -p '' true 2>&1); then echo "root ok"
      else printf 'root denied %s\n' "$(printf '%s' "$err" | tr '\n' ' ')"; fi ;;
  esac
fi
has() { for p in "$@"; do [ -x "$p" ] && return 0; command -v "${p##*/}" >/dev/null 2>&1 && return 0; done; return 1; }
if has /usr/sbin/logrotate; then echo "logrotate yes"; else echo "logrotate no"; fi
if [ -d /etc/cron.d ] && has /usr/sbin/cron /usr/sbin/crond; then echo "cron yes"; else echo "cron no"; fi
if command -v udevadm >/dev/null 2>&1; then echo "udevadm yes"; else echo "udevadm no"; fi
