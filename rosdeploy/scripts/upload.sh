# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_guard.sh

release=$1; arm=$2; shift 2
# The pull is done: the guard's deadline now covers the steps up to the start.
[ -z "$arm" ] || rearm "${arm%% *}" prepare "${arm#* }" || exit 6
tmp=$dir/releases/.tmp-$release-$$
rm -rf "$tmp"; mkdir -p "$tmp"
tar -x -f - -C "$tmp" --no-same-owner || { rm -rf "$tmp"; echo "upload incomplete: tar failed" >&2; exit 5; }
chmod 0600 "$tmp/.env" 2>/dev/null || true
# A release with this id holds the same files by construction (the id is their digest):
# replace it whole so a half-written one from a cut connection never survives.
rm -rf "$dir/releases/$release"
mv "$tmp" "$dir/releases/$release"
# ROS log dirs survive releases. Created here, not by Docker (which would make them
# root-owned and unwritable for a non-root container user whose uid the robot does
# not know): sticky and world-writable, like /tmp.
for service in "$@"; do
  [ -d "$dir/logs/$service" ] || { mkdir -p "$dir/logs/$service" && chmod 1777 "$dir/logs/$service"; }
done
