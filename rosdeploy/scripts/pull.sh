# shellcheck shell=sh

set -u
# Pull what is missing, all images at once; keep going to report every failure.
fail=0; pids=""
for img in "$@"; do
  if ! docker image inspect "$img" >/dev/null 2>&1; then
    # shellcheck disable=SC2046 # a file name: cksum prints digits
    ( docker pull -q "$img" >/dev/null 2>/tmp/.rosdeploy-pull.$$.$(printf '%s' "$img" | cksum | cut -d' ' -f1) ) &
    pids="$pids $!"
  fi
done
for p in $pids; do wait "$p" || fail=1; done
for img in "$@"; do
  # range, not join: Docker 20.10's template sees RepoDigests as []interface{} and join fails
  id=$(docker image inspect --format '{{.Id}} {{range $i, $d := .RepoDigests}}{{if $i}},{{end}}{{$d}}{{end}}' \
    "$img" 2>/dev/null)
  if [ -n "$id" ]; then printf 'ok %s %s\n' "$img" "$id"
  else
    f=/tmp/.rosdeploy-pull.$$.$(printf '%s' "$img" | cksum | cut -d' ' -f1)
    printf 'missing %s %s\n' "$img" "$(tr '\n' ' ' < "$f" 2>/dev/null)"
  fi
done
rm -f /tmp/.rosdeploy-pull.$$.*
exit $fail
