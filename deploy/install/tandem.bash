# bash completion for tandem, tandem-server and tandem-client (installed by `cmake --install`
# under share/bash-completion/completions/). Flags come from each program's own --help, so
# they never drift from the code; file arguments complete as files.
_tandem_complete() {
  local cur prog sub
  cur=${COMP_WORDS[COMP_CWORD]}
  prog=${COMP_WORDS[0]}
  case "${prog##*/}" in
    tandem) subs="extract generate measure info simulate view" ;;
    tandem-client) subs="stream watch view info health" ;;
    *) subs="" ;;
  esac
  if [ -n "$subs" ] && [ "$COMP_CWORD" -eq 1 ]; then
    mapfile -t COMPREPLY < <(compgen -W "$subs --help --version" -- "$cur")
    return
  fi
  sub=""
  [ -n "$subs" ] && sub=${COMP_WORDS[1]}
  if [[ "$cur" == -* ]]; then
    local flags
    # shellcheck disable=SC2086
    flags=$("$prog" $sub --help 2>&1 | grep -oE -- '--[a-z0-9][a-z0-9-]*' | sort -u)
    mapfile -t COMPREPLY < <(compgen -W "$flags" -- "$cur")
    return
  fi
  mapfile -t COMPREPLY < <(compgen -f -- "$cur")
}
complete -o filenames -F _tandem_complete tandem tandem-server tandem-client
