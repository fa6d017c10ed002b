# Sourced by the benchmark scripts (BIN and WORK set).
#
# fractal_asset N: the path of an N x N fractal asset in $WORK, made once
# (synth, ingest, the GeoTIFF removed).
fractal_asset() {
  local asset="$WORK/fractal_$1.tbake"
  if [ ! -d "$asset" ]; then
    "$BIN" synth fractal --size "$1x$1" -o "$WORK/fractal_$1.tif" -q
    "$BIN" ingest "$WORK/fractal_$1.tif" -o "$asset" -q
    rm -f "$WORK/fractal_$1.tif"
  fi
  echo "$asset"
}

# spread [FORMAT]: min, median and max of the numbers on stdin, one a
# line, each printed with FORMAT (printf's; 3 digits unless given).
spread() {
  local f=${1:-%.3g}
  sort -g | awk -v f="$f" '{ v[NR] = $1 } END { printf f " " f " " f "\n", v[1], (NR % 2 ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2), v[NR] }'
}

# wall CMD...: runs CMD (its output dropped) and prints the wall seconds
# it took, to the nanosecond clock's precision (a bake of a few posts takes
# hundredths of a second, below /usr/bin/time's resolution).
wall() {
  local start
  start=$(date +%s.%N)
  "$@" >/dev/null
  awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { print b - a }'
}

# run_in_cgroup LIMIT_MIB LOG CMD...
# runs CMD under /usr/bin/time -v (output to LOG) inside a cgroup v1 memory
# limit of LIMIT_MIB, after dropping the page cache so that every page the
# run maps is charged to it, and sets PEAK_ANON_MIB (the process's own
# memory, sampled from the cgroup's rss every 0.2 s; the rest of its usage
# is page cache of mapped files, which the limit keeps reclaiming) and
# PEAK_CGROUP_MIB. Returns 1 without running anything where there is no
# cgroup to use (not root, or no v1 memory controller).
run_in_cgroup() {
  local limit=$1 log=$2
  shift 2
  local cg=/sys/fs/cgroup/memory/terrabake-bench
  mkdir -p "$cg" 2>/dev/null && echo $((limit << 20)) > "$cg/memory.limit_in_bytes" 2>/dev/null || return 1
  echo 0 > "$cg/memory.max_usage_in_bytes"
  sync && echo 3 > /proc/sys/vm/drop_caches
  bash -c "echo \$\$ > $cg/cgroup.procs && exec /usr/bin/time -v $*" > "$log" 2>&1 &
  local peak=0 rss
  while kill -0 $! 2>/dev/null; do
    rss=$(awk '$1 == "rss" { print $2 }' "$cg/memory.stat")
    [ "$rss" -gt "$peak" ] && peak=$rss
    sleep 0.2
  done
  wait $!
  PEAK_ANON_MIB=$((peak >> 20))
  PEAK_CGROUP_MIB=$(( $(cat "$cg/memory.max_usage_in_bytes") >> 20 ))
}

# report_limited LIMIT_MIB LOG PATTERN CMD...
# runs CMD with run_in_cgroup and prints its lines matching PATTERN, its
# time, peak RSS and exit status, and the cgroup's peaks; without a cgroup,
# runs it under /usr/bin/time -v alone and prints peak RSS.
report_limited() {
  local limit=$1 log=$2 pattern=$3
  shift 3
  if run_in_cgroup "$limit" "$log" "$@"; then
    grep -E "$pattern|Elapsed|Maximum resident|Exit" "$log"
    echo "cgroup limit $limit MiB; peak anonymous memory $PEAK_ANON_MIB MiB; peak usage with page cache $PEAK_CGROUP_MIB MiB"
  else
    echo "(no memory cgroup: peak RSS only)"
    /usr/bin/time -v "$@" 2>&1 | grep -E "$pattern|Elapsed|Maximum resident"
  fi
}
