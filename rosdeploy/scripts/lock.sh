# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_lock.sh
. ./_guard.sh

take_lock "$1" "$2" "$3" || exit $?
shift 3
[ $# -eq 0 ] && exit 0
arm "$@"; armed=$?
[ $armed = 0 ] && exit 0
rm -rf "$dir/.lock"
if [ $armed = 6 ]; then   # a guard is ending an interrupted run here: the robot is its until then
  printf 'held {"by": "the deploy guard (ending an interrupted run)", "run": "guard"}\n'
  exit 3
fi
echo "cannot arm the deploy guard in $dir/.guard: check the deploy root's owner and permissions" >&2
exit 1
