# Robot side of the image step. Arguments: quads `name source want stages`:
#   name    the normal name the compose file runs (…/demo/driver:1.0.0)
#   source  what to pull: the registry's or the forward's name by digest (…@sha256:…)
#   want    the pinned image id (sha256:…), or @sha256:… (a multi-platform index: its digest)
#   stages  comma-separated digests of stage images to pull first (see relay.py), or -
# Prints `ok NAME ID DIGESTS` per image holding the pinned content, else `missing NAME WHY`.
set -u
tmp=${TMPDIR:-/tmp}/.rosdeploy-pull.$(id -u)
# A pull left by a dropped link (its sshd session not yet timed out) would keep the layer
# it was fetching busy: stop it, so this pull does not wait behind it.
if [ -f "$tmp.pids" ]; then
  while read -r p; do
    [ "$(cat "/proc/$p/comm" 2>/dev/null)" = docker ] && kill "$p" 2>/dev/null
  done <"$tmp.pids"
fi
: >"$tmp.pids"

# name: "ID DIGEST,DIGEST..." of the image the engine has under that name, or nothing. One
# docker CLI start per image and look (a Go program: ~20-60 ms on a busy robot).
info() {
  # range, not join: Docker 20.10's template sees RepoDigests as []interface{} and join fails
  docker image inspect --format '{{.Id}} {{range $i, $d := .RepoDigests}}{{if $i}},{{end}}{{$d}}{{end}}' \
    "$1" 2>/dev/null
}

holds() {   # info want source: does the image that `info` describes hold the pin?
  case $2 in
    @*) case $1 in *"$2"*) return 0 ;; esac; return 1 ;;
  esac
  [ "${1%% *}" = "$2" ] || return 1
  # From a registry, also its digest under the registry's name (status and people read it);
  # a pull of an image the engine holds sends the manifest only.
  case $3 in 127.0.0.1:*) return 0 ;; esac
  case $1 in *"@${3#*@}"*) return 0 ;; esac
  return 1
}

pull() {    # ref err
  docker pull -q "$1" >/dev/null 2>"$2" &
  echo $! >>"$tmp.pids"
  wait $!
}

fetch() {   # name source want stages err: the image by digest, then its normal name
  case $2 in 127.0.0.1:*)
    if [ "${3#@}" = "$3" ] && docker image inspect "$3" >/dev/null 2>&1; then
      docker tag "$3" "$1" 2>"$5"; return    # the engine holds these bytes already
    fi ;;
  esac
  # Each stage holds its first layers once it arrives, whatever happens to the rest.
  for stage in $(echo "$4" | tr ',' ' '); do
    [ "$stage" = - ] || pull "${2%@*}@$stage" "$5" || return 1
  done
  pull "$2" "$5" || return 1
  docker tag "$2" "$1" 2>>"$5" || return 1
  case $2 in 127.0.0.1:*) [ "${3#@}" = "$3" ] && docker rmi "$2" >/dev/null 2>&1 ;; esac
  return 0    # the forward's name is gone with the forward: keep only the normal one
}

start() {   # every image not holding its pin, all at once (dockerd shares common layers)
  i=0; pids=""
  while [ $# -ge 4 ]; do
    i=$((i+1))
    if ! holds "$(info "$1")" "$3" "$2"; then
      fetch "$1" "$2" "$3" "$4" "$tmp.$i.err" &
      pids="$pids $!"
    fi
    shift 4
  done
  for p in $pids; do wait "$p"; done
  rm -f "$tmp.pids"
}

report() {
  i=0; fail=0
  while [ $# -ge 4 ]; do
    i=$((i+1))
    got=$(info "$1")
    if holds "$got" "$3" "$2"; then
      printf 'ok %s %s\n' "$1" "$got"
    else
      fail=1
      have=${got%% *}
      why=$(tr '\n' ' ' <"$tmp.$i.err" 2>/dev/null)
      printf 'missing %s %s\n' "$1" "${why:-holds ${have:-nothing}, not the pinned $3}"
    fi
    rm -f "$tmp.$i.err"
    shift 4
  done
  return $fail
}

start "$@"
report "$@" || exit 1
# Every image holds its pin: the stage images (this run's and a dropped run's) go, in the
# background (the report is out; the SSH channel closes with our own output).
(
  stages=$(docker images -q --filter label=io.rosdeploy.stage | sort -u)
  # shellcheck disable=SC2086  # image ids: plain hex words
  [ -z "$stages" ] || docker rmi -f $stages
) </dev/null >/dev/null 2>&1 &
