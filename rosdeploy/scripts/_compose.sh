# shellcheck shell=sh
# shellcheck disable=SC2154 # flavor (v1 or v2) is set by the script, from the robot's state
# Compose command: v2 plugin or v1 binary, chosen by the caller after `state`, run in the release.
#
# Compose fills ${VAR} in compose.yml from the shell's environment before the .env beside it: a
# robot whose /etc/environment or login profile sets ROS_DOMAIN_ID (ROS's own setup guides say to)
# would run on its own domain, not the release's. So compose runs without the names .env sets (a
# subshell: the caller keeps them). PATH and HOME stay: docker needs them to run and to read its
# config. `command unset`: a read-only name is left, not a reason for the shell to exit.
compose() (
  if [ -f .env ]; then
    while IFS= read -r line || [ -n "$line" ]; do
      name=${line%%=*}
      case $name in PATH|HOME|"$line"|*[!A-Za-z0-9_]*|[0-9]*|'') ;; *) command unset "$name" 2>/dev/null || :;; esac
    done < .env
  fi
  if [ "$flavor" = v1 ]; then docker-compose "$@"; else docker compose "$@"; fi
)
