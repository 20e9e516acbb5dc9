# shellcheck shell=sh source-path=SCRIPTDIR
# A rollback's first round trip: the lock, then the state read under it (what it shows
# cannot change before the switch), with the kept releases' manifests.
. ./_prologue.sh
. ./_files.sh
. ./_lock.sh
. ./_guard.sh

# Nothing deployed here: nothing to switch, so nothing to lock (and no directory to make).
if [ -d "$dir/releases" ]; then answer=$(take_lock "$1" "$2" "$3"); locked=$?; else answer="nothing deployed"; locked=0; fi
mode=switch; shift 3
# The rollback's guard (guard.py), armed under the lock before the state is read: the
# target is not known yet, the `up` that switches re-arms it with the target.
if [ $locked = 0 ] && [ $# -gt 0 ] && [ -d "$dir/releases" ]; then
  arm "$@"; armed=$?
  if [ $armed != 0 ]; then
    rm -rf "$dir/.lock"; locked=3
    answer='held {"by": "the deploy guard (ending an interrupted run)", "run": "guard"}'
    if [ $armed != 6 ]; then
      echo "cannot arm the deploy guard in $dir/.guard: check the deploy root's owner and permissions" >&2
      locked=1
    fi
  fi
fi
printf '%s\n' "$answer"
. ./_state.sh

exit $locked
