# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_guard.sh

# A step that waits on the robot (the readiness gate) keeps the guard's deadline ahead of it.
rearm "${1%% *}" prepare "${1#* }" || exit 6
