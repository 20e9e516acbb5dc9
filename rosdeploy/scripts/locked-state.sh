# shellcheck shell=sh source-path=SCRIPTDIR
# A rollback's first round trip: the lock, then the state read under it (what it shows
# cannot change before the switch), with the kept releases' manifests.
. ./_prologue.sh
. ./_files.sh
. ./_lock.sh

# Nothing deployed here: nothing to switch, so nothing to lock (and no directory to make).
if [ -d "$dir/releases" ]; then take_lock "$1" "$2" "$3"; locked=$?; else echo "nothing deployed"; locked=0; fi
mode=switch; shift 3
. ./_state.sh

exit $locked
