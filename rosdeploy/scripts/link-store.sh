# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh

release=$1
src=$dir/releases/$release/store
mkdir -p "$dir/store"
# Name by name, not entry by entry: an entry (one content digest) may be here already under
# another name (a renamed target, or another file with the same content), and a name may
# start with "." (`*` alone misses it). A name missing here is a mount source Docker would
# create as an empty directory on the robot.
tmp=$dir/store/.tmp-$$
if [ -d "$src" ]; then
  for entry in "$src"/*/; do
    [ -d "$entry" ] || continue
    key=$(basename "$entry")
    for f in "$entry"* "$entry".[!.]* "$entry"..?*; do
      [ -f "$f" ] || continue
      dest=$dir/store/$key/${f##*/}
      [ -f "$dest" ] && continue
      # the empty directory Docker made when an earlier release mounted this name while it was missing
      if [ -d "$dest" ]; then rmdir "$dest" || exit 5; fi
      mkdir -p "$dir/store/$key" "$tmp" || exit 5
      # linked or copied beside it, then renamed into place: a cut connection never leaves half a file
      ln "$f" "$tmp/f" 2>/dev/null || cp -p "$f" "$tmp/f" || exit 5
      mv -f "$tmp/f" "$dest" || exit 5
    done
  done
fi
rm -rf "$tmp"
# Entries no kept release holds any more (their releases were pruned).
for entry in "$dir/store"/*/; do
  [ -d "$entry" ] || continue
  key=$(basename "$entry")
  set -- "$dir"/releases/*/store/"$key"
  [ -e "$1" ] || rm -rf "$entry"
done
