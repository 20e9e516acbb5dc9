# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_files.sh

mode=$1; want_compose=$2; want_gpu=$3; shift 3
. ./_state.sh
