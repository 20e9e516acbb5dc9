# shellcheck shell=sh
# shellcheck disable=SC2154 # flavor (v1 or v2) is set by the script, from the robot's state
# Compose command: v2 plugin or v1 binary, chosen by the caller after `state`, run in the release.
#
# Compose fills ${VAR} in compose.yml from the shell's environment before the .env beside it: a
# robot whose /etc/environment or login profile sets ROS_DOMAIN_ID (ROS's own setup guides say to)
# would run on its own domain, not the release's. So compose runs without the names .env sets (a
# subshell: the caller keeps them). PATH and HOME stay: docker needs them to run and to read its
# config. `command unset`: a read-only name is left, not a reason for the shell to exit. The
# command is chosen first: .env may name one of this script's own variables (`flavor`).
# A name is read as Compose reads it: `export NAME=` and blanks around it (a user's env.j2).
compose() (
  if [ "$flavor" = v1 ]; then set -- docker-compose "$@"; else set -- docker compose "$@"; fi
  if [ -f .env ]; then
    while IFS= read -r line || [ -n "$line" ]; do
      case $line in *=*) ;; *) continue;; esac
      name=${line%%=*}
      name=${name#"${name%%[! 	]*}"}
      case $name in export[' 	']*) name=${name#export}; name=${name#"${name%%[! 	]*}"};; esac
      name=${name%"${name##*[! 	]}"}
      case $name in PATH|HOME|*[!A-Za-z0-9_]*|[0-9]*|'') ;; *) command unset "$name" 2>/dev/null || :;; esac
    done < .env
  fi
  "$@"
)
