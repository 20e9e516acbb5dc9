# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_guard.sh

token=$1
# The run ends: its guard goes with it, unless it took over (then the lock is its to release).
disarm "$token" || exit 0
# Only remove a lock we hold: another run may have broken ours and taken it.
if grep -qF "$token" "$dir/.lock/owner" 2>/dev/null; then rm -rf "$dir/.lock"; fi
