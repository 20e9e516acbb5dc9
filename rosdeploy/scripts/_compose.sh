# shellcheck shell=sh
# shellcheck disable=SC2154 # flavor (v1 or v2) is set by the script, from the robot's state
# Compose command: v2 plugin or v1 binary, chosen by the caller after `state`.

compose() { if [ "$flavor" = v1 ]; then docker-compose "$@"; else docker compose "$@"; fi; }
