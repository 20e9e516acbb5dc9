# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh

release=$1
src=$dir/releases/$release/store
mkdir -p "$dir/store"
if [ -d "$src" ]; then
  for entry in "$src"/*/; do
    [ -d "$entry" ] || continue
    key=$(basename "$entry")
    [ -d "$dir/store/$key" ] && continue
    # a temp dir renamed into place: a cut connection never leaves half an entry
    tmp=$dir/store/.tmp-$key-$$
    rm -rf "$tmp"; mkdir -p "$tmp"
    for f in "$entry"*; do ln "$f" "$tmp/" 2>/dev/null || cp -p "$f" "$tmp/" || exit 5; done
    mv "$tmp" "$dir/store/$key"
  done
fi
# Entries no kept release holds any more (their releases were pruned).
for entry in "$dir/store"/*/; do
  [ -d "$entry" ] || continue
  key=$(basename "$entry")
  set -- "$dir"/releases/*/store/"$key"
  [ -e "$1" ] || rm -rf "$entry"
done
