# shellcheck shell=sh source-path=SCRIPTDIR
. ./_prologue.sh

release=$1; shift
n=0
for name in "$@"; do
  n=$((n + 1))
  printf '\n@@file%s\n' "$n"; cat "$dir/releases/$release/$name" 2>/dev/null || printf '!!absent!!'
done
printf '\n@@images\n'
while read -r img; do
  [ -n "$img" ] && { docker image inspect "$img" >/dev/null 2>&1 && echo "present $img" || echo "missing $img"; }
done
printf '\n@@end\n'
