#!/bin/bash
# Draw the independent cases and diagnose each with the greybox CLI.
#   scripts/independent/run.sh target/release/greybox OUT_DIR
# (SEEDS="4 5 6" draws other seeds than the default 1 2 3)
# needs python3 with numpy; writes OUT_DIR/cases/<case>/{train,validate}.csv,
# OUT_DIR/r/<case>.{txt,json} and OUT_DIR/r/times.txt, then prints the table
# of scripts/independent/eval.py.
set -u
BIN=$1; OUT=$2; HERE=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$OUT/cases" "$OUT/r"; : > "$OUT/r/times.txt"
for f in linear accel third-order duffing tanh-sensor input-sq in-sat friction bouc-wen preisach-smooth backlash-in process ar-noise; do
  for s in ${SEEDS:-1 2 3}; do python3 "$HERE/gen.py" $f $s "$OUT/cases/$f-$s" > /dev/null || exit 1; done
done
for d in "$OUT"/cases/*/; do
  n=$(basename "$d"); s=$(date +%s.%N)
  "$BIN" diagnose "$d/train.csv" --validate "$d/validate.csv" --quiet --json "$OUT/r/$n.json" > "$OUT/r/$n.txt" 2>&1; rc=$?
  e=$(date +%s.%N); echo "$n $rc $(echo "$e - $s" | bc)" >> "$OUT/r/times.txt"
done
python3 "$HERE/eval.py" "$OUT"
