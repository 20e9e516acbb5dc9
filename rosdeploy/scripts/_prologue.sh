# shellcheck shell=sh
# shellcheck disable=SC2034 # dir is for the script this prologue starts
# Shared prologue: resolve "~/..." against the SSH user's home (the remote shell
# cannot expand a quoted "~"), and define the project directory.

set -u
root=$1; project=$2; shift 2
# shellcheck disable=SC2088 # a literal "~" (the inventory's), resolved here against $HOME
case $root in "~") root=$HOME;; "~/"*) root=$HOME/${root#"~/"};; esac
dir=$root/$project
