# shellcheck shell=sh
# Prints `held MTIME FIRST-LINE` when the lock file exists, nothing otherwise.

p=$1
# shellcheck disable=SC2088 # a literal "~" (the inventory's), resolved here against $HOME
case $p in "~/"*) p=$HOME/${p#"~/"};; esac
[ -e "$p" ] || exit 0
m=$(stat -c %Y "$p" 2>/dev/null || echo "?")
l=""; [ -r "$p" ] && IFS= read -r l < "$p"
printf 'held %s %s\n' "$m" "$l"
