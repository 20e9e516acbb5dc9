# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_guard.sh

mkdir -p "$dir" && printf '%s\n' "$1" >> "$dir/history.jsonl" || exit $?
[ -z "${2:-}" ] || rearm "${2%% *}" start "${2#* }"
