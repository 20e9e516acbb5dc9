# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_files.sh

show "$dir/releases/$1/manifest.json"
