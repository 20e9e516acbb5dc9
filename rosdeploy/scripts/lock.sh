# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_lock.sh
. ./_guard.sh

# take_lock's answer is printed only once it stands: a lock given back because the guard
# could not be armed must not read "locked" before its "held".
answer=$(take_lock "$1" "$2" "$3"); taken=$?
if [ $taken != 0 ]; then [ -z "$answer" ] || printf '%s\n' "$answer"; exit $taken; fi
# $4 yes: the caller decided on a state read before it waited for the lock; if another run
# switched the robot since (`current` moved), that decision is stale. Compared under the lock,
# before the guard is armed with a `previous` that would be wrong.
if [ "$4" = yes ] && [ "$(readlink "$dir/current" 2>/dev/null || true)" != "$5" ]; then
  rm -rf "$dir/.lock"; echo moved; exit 4
fi
shift 5
if [ $# -eq 0 ]; then printf '%s\n' "$answer"; exit 0; fi
arm "$@"; armed=$?
if [ $armed = 0 ]; then printf '%s\n' "$answer"; exit 0; fi
rm -rf "$dir/.lock"
if [ $armed = 6 ]; then   # a guard is ending an interrupted run here: the robot is its until then
  printf 'held {"by": "the deploy guard (ending an interrupted run)", "run": "guard"}\n'
  exit 3
fi
echo "cannot arm the deploy guard in $dir/.guard: check the deploy root's owner and permissions" >&2
exit 1
