# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_compose.sh

release=$1; flavor=$2
cd "$dir/releases/$release" && compose -p "$project" -f compose.yml down --remove-orphans 2>&1
