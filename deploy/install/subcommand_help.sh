#!/bin/sh
# Writes a help2man --include file: one section per subcommand of PROG with its --help
# text (roff-escaped: backslashes, and lines that would start with a roff control
# character), so that the man page documents every subcommand's flags, not only the
# top-level usage.  subcommand_help.sh PROG OUT SUB...
set -eu
prog=$1 out=$2
shift 2
: > "$out"
[ $# -gt 0 ] || printf '[SEE ALSO]\ntandem(1), tandem-client(1), tandem-server(1)\n' >> "$out"
for sub in "$@"; do
  printf '[%s]\n.nf\n' "$(echo "$prog $sub" | sed 's|.*/||' | tr '[:lower:]' '[:upper:]')" >> "$out"
  "$prog" "$sub" --help 2>&1 | sed -e 's/\\/\\e/g' -e "s/^\\([.']\\)/\\\\\\&\\1/" >> "$out"
  printf '.fi\n\n' >> "$out"
done
