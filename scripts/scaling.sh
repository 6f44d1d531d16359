#!/usr/bin/env bash
# The scaling measurements: the parallel queries' paired speed-ups, the
# plugin's `town` frame and Bevy's visibility served by the index against
# Bevy's own (multi-threaded executor) on 1, 2, 4, 8 and 16 threads, each
# run confined to that many cores with `taskset` and given a task pool of
# exactly that many threads.
#
#   scripts/scaling.sh build        release binaries into scaling-bin/
#                                   (git-ignored; needs the Rust toolchain)
#   scripts/scaling.sh run OUT      runs them for every thread count the
#                                   machine has cores for (needs only the
#                                   binaries), results in OUT/scaling.md
set -euo pipefail
cd "$(dirname "$0")/.."

case "${1:-}" in
build)
    mkdir -p scaling-bin
    # The bench binary: cargo prints where it put it.
    bench=$(cargo bench --features parallel --bench parallel --no-run 2>&1 |
        sed -n 's/.*Executable .*(\(.*\)).*/\1/p' | tail -1)
    cp "$bench" scaling-bin/parallel
    cargo build --release --example town --features parallel,multi_threaded
    cp target/release/examples/town scaling-bin/town
    bench=$(cargo bench --features bevy_light,multi_threaded --bench bevy_visibility --no-run 2>&1 |
        sed -n 's/.*Executable .*(\(.*\)).*/\1/p' | tail -1)
    cp "$bench" scaling-bin/bevy_visibility
    # Smaller to carry to another machine (the Bevy bench is ~40 MB).
    strip scaling-bin/* 2>/dev/null || true
    ls -l scaling-bin
    ;;
run)
    out=${2:?"usage: scripts/scaling.sh run OUT"}
    mkdir -p "$out"
    report="$out/scaling.md"
    cores=$(nproc)
    {
        echo "# Scaling on $(nproc) cores: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | xargs)"
        echo
        # Whether `taskset -c 0-(n-1)` picks n cores or hyperthread siblings.
        echo '```'
        lscpu 2>/dev/null | grep -E '^(Thread|Core|Socket|NUMA node|L2|L3)' || true
        lscpu -e=CPU,CORE,SOCKET 2>/dev/null | head -17 | tr '\n' ' ' || true
        echo
        echo '```'
        echo
    } >"$report"
    for n in 1 2 4 8 16; do
        if [ "$n" -gt "$cores" ]; then
            break
        fi
        last=$((n - 1))
        echo "## $n threads (taskset -c 0-$last)" >>"$report"
        echo >>"$report"
        BEVY_RTREE_THREADS=$n BEVY_RTREE_PAIRED_ONLY=1 BEVY_RTREE_OUT="$out/paired_$n.md" \
            taskset -c "0-$last" scaling-bin/parallel --bench >"$out/parallel_$n.log" 2>&1 || true
        cat "$out/paired_$n.md" >>"$report" 2>/dev/null || tail -5 "$out/parallel_$n.log" >>"$report"
        echo >>"$report"
        echo '`town` through the plugin, 300 frames:' >>"$report"
        taskset -c "0-$last" scaling-bin/town --frames 300 --threads "$n" 2>&1 |
            grep -E 'task pool|summary' >>"$report" || true
        echo >>"$report"
        if [ -x scaling-bin/bevy_visibility ]; then
            echo "Bevy's visibility, multi-threaded executor (Bevy's time ÷ ours):" >>"$report"
            echo >>"$report"
            BEVY_RTREE_THREADS=$n taskset -c "0-$last" scaling-bin/bevy_visibility 2>&1 |
                grep -E '^\||compute pool' >>"$report" || true
            echo >>"$report"
        fi
        rm -f "$out/paired_$n.md" "$out/parallel_$n.log"
    done
    cat "$report"
    ;;
*)
    echo "usage: scripts/scaling.sh build | run OUT" >&2
    exit 2
    ;;
esac
