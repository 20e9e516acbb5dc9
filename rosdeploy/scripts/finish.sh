# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh
. ./_guard.sh
. ./_files.sh

release=$1; record=$2; keep=$3; run=${4:-}
cd "$dir" || exit 4
# The same step that switches `current` disarms the run's guard; if the guard took over
# already, this run must not switch.
[ -z "$run" ] || disarm "$run" strict || exit 6
ln -sfn "releases/$release" current.tmp && mv -T current.tmp current
# mtime = activation order, so pruning keeps the releases that last ran, not the last uploaded
touch "releases/$release"
append history.jsonl "$record"
# Prune: keep the newest $keep releases by mtime, never the current one; then the
# images only pruned releases used (each release lists its images in images.txt).
old_imgs=""
# Only names rosdeploy gives (<version tag>-<12 hex>): a copy named "X copy" is not ours,
# and split on its space it would have pruned X itself.
# shellcheck disable=SC2010 # ls -t for the mtime order; the names kept are plain words
for old in $(ls -1t releases | grep -x '[A-Za-z0-9_][A-Za-z0-9_.-]*-[0-9a-f]\{12\}' | grep -vxF "$release" \
             | tail -n +"$keep"); do
  old_imgs="$old_imgs $(cat "releases/$old/images.txt" 2>/dev/null)"
  rm -rf "releases/$old"; printf 'pruned %s\n' "$old"
done
kept=$(cat releases/*/images.txt 2>/dev/null | sort -u)
for img in $old_imgs; do
  printf '%s\n' "$kept" | grep -qxF "$img" \
    || { docker image rm "$img" >/dev/null 2>&1 && printf 'removed %s\n' "$img"; }
done
exit 0
