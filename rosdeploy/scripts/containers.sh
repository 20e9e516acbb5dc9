# shellcheck shell=sh source-path=SCRIPTDIR
. ./_inspect.sh

project=$1; shift
if [ $# -gt 0 ]; then
  # Known containers by name: one docker CLI start per poll, not two (its whole cost on the
  # robot). A name that is gone is left out; the caller lists the project again then.
  docker inspect --format "$fmt" "$@" 2>/dev/null
else
  ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project" 2>/dev/null)
  # shellcheck disable=SC2086 # container ids, one a word
  [ -z "$ids" ] || docker inspect --format "$fmt" $ids 2>/dev/null
fi
exit 0
