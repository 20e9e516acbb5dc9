# shellcheck shell=sh
# Shell built-ins for the small files: each program started (cat, ls, grep) is a fork
# and an exec, and `status` runs this on every robot at once.

show() { [ -r "$1" ] || return 0; while IFS= read -r line || [ -n "$line" ]; do printf '%s\n' "$line"; done < "$1"; }
contains() { case $(show "$1") in *"$2"*) return 0 ;; esac; return 1; }
