# shellcheck shell=sh
# Shell built-ins for the small files: each program started (cat, ls, grep) is a fork
# and an exec, and `status` runs this on every robot at once.

# Regular files only: a link to /dev/zero or a fifo where a small file belongs would spin or hang.
show() { [ -f "$1" ] && [ -r "$1" ] || return 0; while IFS= read -r line || [ -n "$line" ]; do printf '%s\n' "$line"; done < "$1"; }
# show_head FILE BYTES: a file another program could have grown (the lock's owner record is a
# line; one of 70 MB would take `status` 45 s to read line by line and overflow its output)
show_head() { [ -f "$1" ] && [ -r "$1" ] || return 0; head -c "$2" "$1" | { while IFS= read -r line || [ -n "$line" ]; do printf '%s\n' "$line"; done; }; }
contains() { case $(show "$1") in *"$2"*) return 0 ;; esac; return 1; }
# append FILE LINE: a line of its own, also after a last line a power loss cut short
append() {
  [ ! -s "$1" ] || [ -z "$(tail -c 1 "$1")" ] || printf '\n' >> "$1"
  printf '%s\n' "$2" >> "$1"
}
