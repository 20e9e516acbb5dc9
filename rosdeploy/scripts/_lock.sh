# shellcheck shell=sh source-path=SCRIPTDIR
# take_lock OWNER BREAK_STALE DEAD_RUN: prints `locked` (0) or `held <owner>` (3).
. ./_prologue.sh

take_lock() {
  owner=$1; break_stale=$2; dead_run=${3:-}
  mkdir -p "$dir/releases" "$dir/logs" || { echo "cannot create $dir (owned by another user?)" >&2; return 1; }
  if [ "$break_stale" = yes ]; then rm -rf "$dir/.lock" "$dir/.lock-break"; fi
  if [ -n "$dead_run" ] && mkdir "$dir/.lock-break" 2>/dev/null; then
    # Remove the lock of a run the caller proved dead, and only that lock. .lock-break keeps
    # out a second run that found it dead too: that one then finds the lock held by us.
    if grep -qF "\"run\": \"$dead_run\"" "$dir/.lock/owner" 2>/dev/null; then rm -rf "$dir/.lock"; fi
    taken=no
    if mkdir "$dir/.lock" 2>/dev/null; then printf '%s\n' "$owner" > "$dir/.lock/owner"; taken=yes; fi
    rmdir "$dir/.lock-break"
    if [ $taken = yes ]; then echo locked; return 0; fi
  fi
  if mkdir "$dir/.lock" 2>/dev/null; then
    printf '%s\n' "$owner" > "$dir/.lock/owner"
    echo locked
  elif [ -d "$dir/.lock" ]; then
    printf 'held '; head -c 4096 "$dir/.lock/owner" 2>/dev/null || echo '{}'
    return 3
  else
    echo "cannot create the lock $dir/.lock: check the deploy root's owner and permissions" >&2
    return 1
  fi
}
