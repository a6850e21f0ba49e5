# Shell helpers of the memory benchmarks (sizing.sh, depth.sh), sourced after they set
# $bin (the programs' directory).

# bench_start NAME: checks that $bin holds the programs, makes the scratch directory $work in
# /dev/shm, and removes it (and stops a server left running) on exit.
bench_start() {
  local b
  for b in tandem tandem-server tandem-client; do
    [ -x "$bin/$b" ] || { echo "$1: $bin/$b not found (build first)" >&2; exit 2; }
  done
  work=$(mktemp -d "/dev/shm/tandem-$1.XXXXXX")
  server_pid=""
  trap 'bench_cleanup' EXIT
}
bench_cleanup() {
  [ -n "$server_pid" ] && kill "$server_pid" 2>/dev/null || true
  rm -rf "$work"
}

mib() { awk -v k="$1" 'BEGIN { printf "%.1f MiB", k / 1024 }'; }
# Runs a command under /usr/bin/time -v; prints "peak_kib wall_s".
timed() {
  /usr/bin/time -v "$@" > /dev/null 2> "$work/time.txt" || { cat "$work/time.txt" >&2; exit 1; }
  awk -F': ' '/Maximum resident set size/ { k = $2 }
              /Elapsed \(wall clock\)/ { n = split($2, p, ":"); s = p[n] + 60 * p[n-1]; if (n == 3) s += 3600 * p[1] }
              END { printf "%d %.2f\n", k, s }' "$work/time.txt"
}
status_kib() { awk -v f="$2:" '$1 == f { print $2 }' "/proc/$1/status"; }
start_server() {
  "$bin/tandem-server" --listen 127.0.0.1:0 "$@" > "$work/server.out" 2> "$work/server.err" &
  server_pid=$!
  for _ in $(seq 1 100); do
    grep -q "listening on" "$work/server.out" 2>/dev/null && break
    sleep 0.05
  done
  address=$(sed -n 's/^listening on //p' "$work/server.out")
  [ -n "$address" ] || { cat "$work/server.err" >&2; exit 1; }
  sleep 0.3
  idle_kib=$(status_kib "$server_pid" VmRSS)
}
stop_server() {
  kill -TERM "$server_pid"
  wait "$server_pid" 2>/dev/null || true
  server_pid=""
}
