#!/usr/bin/env bash
# `cmake --install` into a temporary prefix: the three programs, a man page each (from
# --help, every subcommand's flags included) and the bash completion; the installed
# programs run and report the version, and the completion offers subcommands and the
# flags each program's --help lists.   install_test.sh BUILD_DIR
set -euo pipefail
build=$1
prefix=$(mktemp -d /tmp/tandem-install.XXXXXX)
trap 'rm -rf "$prefix"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
cmake --install "$build" --prefix "$prefix" > /dev/null
for p in tandem tandem-server tandem-client; do
  [ -x "$prefix/bin/$p" ] || fail "bin/$p not installed"
  "$prefix/bin/$p" --version | grep -qE "^$p [0-9]+\.[0-9]+\.[0-9]+ \(git [^)]+\)$" \
    || fail "$p --version: $("$prefix/bin/$p" --version 2>&1)"
  [ -f "$prefix/share/bash-completion/completions/$p" ] || fail "completion for $p missing"
done
if grep -q '^TANDEM_HELP2MAN:FILEPATH=.*help2man$' "$build/CMakeCache.txt"; then
  man1="$prefix/share/man/man1"
  # help2man writes the top-level flags as \-\-name; the subcommand sections hold each
  # subcommand's --help as it prints.
  for want in "tandem.1:  --iso C0" "tandem.1:  --follow" 'tandem.1:.SH "TANDEM SIMULATE"' \
              "tandem-server.1:\\-\\-max\\-sessions" "tandem-server.1:\\-\\-metrics\\-listen" \
              "tandem-client.1:  --retries N" 'tandem-client.1:.SH "TANDEM-CLIENT HEALTH"' \
              'tandem-client.1:.SH "TANDEM-CLIENT VIEW"' 'tandem.1:.SH "TANDEM VIEW"'; do
    page=${want%%:*} text=${want#*:}
    [ -f "$man1/$page" ] || fail "man page $page missing"
    grep -qF -- "$text" "$man1/$page" || fail "$page does not mention $text"
  done
  grep -q '^\.TH TANDEM "1" .*"tandem [0-9.]* (git ' "$man1/tandem.1" \
    || fail "tandem.1 has no .TH header with the version"
else
  echo "help2man not found at configure time: man pages not checked"
fi
# The completion, as bash calls it.
export PATH="$prefix/bin:$PATH"
# shellcheck disable=SC1091
source "$prefix/share/bash-completion/completions/tandem"
complete_words() {  # words... ; prints COMPREPLY
  COMP_WORDS=("$@")
  COMP_CWORD=$(( ${#COMP_WORDS[@]} - 1 ))
  COMPREPLY=()
  _tandem_complete
  printf '%s\n' "${COMPREPLY[@]}"
}
complete_words tandem ex | grep -qx extract || fail "tandem ex<TAB> is not extract"
complete_words tandem-client st | grep -qx stream || fail "tandem-client st<TAB> is not stream"
complete_words tandem extract --is | grep -qx -- --iso || fail "tandem extract --is<TAB>"
complete_words tandem-client stream --retr | grep -qx -- --retries \
  || fail "tandem-client stream --retr<TAB>"
complete_words tandem-server --grace | grep -qx -- --grace-seconds \
  || fail "tandem-server --grace<TAB>"
complete_words tandem-client vi | grep -qx view || fail "tandem-client vi<TAB> is not view"
# The browser viewer's page and the parts of three.js it loads, next to bin/ (when the npm
# install was there at configure time), and the installed tandem view serving them.
if [ -f "$(dirname "$0")/../../node_modules/three/build/three.module.js" ]; then
  for f in viewer/index.html viewer/viewer.js three/build/three.module.js \
           three/examples/jsm/loaders/DRACOLoader.js three/examples/jsm/libs/draco/draco_decoder.wasm; do
    [ -s "$prefix/share/tandem/$f" ] || fail "share/tandem/$f not installed"
  done
  "$prefix/bin/tandem" generate sphere --size 12 --out "$prefix/s.json" > /dev/null 2>&1
  "$prefix/bin/tandem" extract --input "$prefix/s.json" --iso 0 --error 0.1 --out "$prefix/s.ply" > /dev/null 2>&1
  out=$("$prefix/bin/tandem" view "$prefix/s.ply" --view 127.0.0.1:0 --linger 0.5 2>&1) \
    || fail "tandem view from the install: $out"
  echo "$out" | grep -q "at http://127.0.0.1:" || fail "tandem view printed no address: $out"
fi
echo "install: ok ($(find "$prefix" -type f | wc -l) files)"
