# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_lock.sh
. ./_guard.sh

# take_lock's answer is printed only once it stands: a lock given back because the guard
# could not be armed must not read "locked" before its "held".
answer=$(take_lock "$1" "$2" "$3"); taken=$?
if [ $taken != 0 ]; then [ -z "$answer" ] || printf '%s\n' "$answer"; exit $taken; fi
shift 3
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
