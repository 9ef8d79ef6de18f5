#!/usr/bin/env bash
# The FL_THERMAL judge (docs/diagnose.md "Judging harness"): score the shipped models
# deploy/models/fl_thermal/d<k>/model.toml on a recording with the columns t_s, rpm, T_1_C…T_16_C and
# d1_um…d5_um (the withheld part of the run, or any other), against d<k>/sim.toml (the static
# regression on the 3 best-correlated temperatures fitted on everything shared). Per channel: RMS of
# measured − predicted over every row of the file, and the cut; then the median cut.
# Usage: scripts/fl-thermal-judge.sh WITHHELD.csv   (RETROCOMP=path/to/retrocomp, default target/debug)
set -euo pipefail
csv=${1:?usage: scripts/fl-thermal-judge.sh WITHHELD.csv}
root=$(cd "$(dirname "$0")/.." && pwd)
bin=${RETROCOMP:-$root/target/debug/retrocomp}
models=$root/deploy/models/fl_thermal
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# col FILE NAME: the values of column NAME, one per line.
col() {
    awk -F, -v name="$2" 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == name) k = i
        if (!k) { print "no column " name " in " FILENAME > "/dev/stderr"; exit 1 }; next }
        { print $k }' "$1"
}

for k in 1 2 3 4 5; do
    col "$csv" "d${k}_um" >"$tmp/meas"
    for m in model sim; do
        "$bin" eval --model "$models/d$k/$m.toml" --path "$csv" >"$tmp/$m.csv"
        col "$tmp/$m.csv" ez_um >"$tmp/$m"
    done
    paste -d, "$tmp/meas" "$tmp/model" "$tmp/sim" | awk -F, -v ch="d$k" '
        { a += ($1 - $2)^2; b += ($1 - $3)^2; n++ }
        END { ra = sqrt(a / n); rb = sqrt(b / n)
              printf "%s: static %.2f µm, model %.2f µm, cut %.1f %%\n", ch, rb, ra, 100 * (1 - ra / rb) }'
done | tee "$tmp/table"
awk '{ sub("%", "", $(NF-1)); print $(NF-1) }' "$tmp/table" | sort -g | sed -n 3p |
    awk '{ printf "median cut %.1f %%\n", $1 }'
