# shellcheck shell=sh
# Host changes, restored by the deploy guard (guard.sh) when it goes back to a release: that
# release's udev rules and log rotation again, reaching root the way the last install did.
# hostchanges-install.sh leaves this script, the root script and their arguments in
# <project>/.host/. No password is kept on the robot: after a `sudo -S` install, the guard
# cannot restore them, and says so.
# $1 the project dir  $2 the release to restore (none: nothing to do)
h=$1/.host; rel=$1/releases/${2:-}
[ -n "${2:-}" ] && [ -d "$rel" ] && [ -f "$h/root.sh" ] && [ -f "$h/args" ] || exit 0
{ read -r how; read -r subsystems; read -r rules; read -r conf; read -r cron; read -r state; } < "$h/args"
case $how in
  direct) sh "$h/root.sh" "$rel" "$rules" "$conf" "$cron" "$state" "$subsystems" ;;
  sudo-n) sudo -n sh "$h/root.sh" "$rel" "$rules" "$conf" "$cron" "$state" "$subsystems" ;;
  *) echo "host changes of $2 not restored: root was reached with $how (no password is kept on the robot)"; exit 1 ;;
esac
