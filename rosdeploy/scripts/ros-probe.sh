# shellcheck shell=sh

c=$1; src=$2; arg=$3
exec docker exec "$c" sh -c '
for f in /opt/ros/*/setup.sh /ros_entrypoint_env.sh; do [ -f "$f" ] && . "$f" >/dev/null 2>&1; done
exec python3 -c "$0" "$1"' "$src" "$arg"
