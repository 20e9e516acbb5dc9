# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_guard.sh
. ./_files.sh

mkdir -p "$dir" && append "$dir/history.jsonl" "$1" || exit $?
[ -z "${2:-}" ] || rearm "${2%% *}" start "${2#* }"
