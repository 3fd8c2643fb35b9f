#!/usr/bin/env bash
# Kill test of transactional output folders: re-runs `anaglyph reconstruct` into a complete
# folder and sends SIGKILL at a uniformly random moment of the run; after every kill the
# folder must verify as one complete run (`anaglyph eval` checks its manifest: every file
# with its size and CRC-32, nothing else). Prints how often the previous folder stayed and
# how often a new complete one had replaced it.
#
#   scripts/kill_test.sh RUNS SPAN_MS [anaglyph binary]
#
# Run from a folder holding `sim/` (anaglyph simulate --scene tabletop --size 320x240
# --out sim); SPAN_MS should cover a whole reconstruct run.
set -uo pipefail
runs=${1:?runs}; span_ms=${2:?span in ms}; bin=${3:-anaglyph}
reconstruct=("$bin" reconstruct --rig sim/rig.toml --out rec --max-disp 24)
"${reconstruct[@]}" >/dev/null 2>&1 || { echo "the first, complete run failed"; exit 1; }
run_id() { grep -o '"run_id": "[^"]*"' rec/manifest.json 2>/dev/null; }
kept=0; replaced=0; broken=0
for _ in $(seq 1 "$runs"); do
    before=$(run_id)
    delay=$(( (RANDOM * 32768 + RANDOM) % span_ms ))
    "${reconstruct[@]}" >/dev/null 2>&1 &
    pid=$!
    sleep "$(printf '%d.%03d' $((delay / 1000)) $((delay % 1000)))"
    kill -9 "$pid" 2>/dev/null
    wait "$pid" 2>/dev/null
    if "$bin" eval --truth sim --recon rec >/dev/null 2>&1; then
        if [ "$before" = "$(run_id)" ]; then kept=$((kept + 1)); else replaced=$((replaced + 1)); fi
    else
        broken=$((broken + 1))
        echo "killed at $delay ms: rec/ does not verify"
    fi
done
echo "$runs kills: previous folder kept $kept, new complete folder $replaced, broken $broken"
