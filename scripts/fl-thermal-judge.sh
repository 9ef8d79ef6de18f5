#!/usr/bin/env bash
# The FL_THERMAL judge (docs/diagnose.md "Judging harness"): score the shipped models of
# deploy/models/fl_thermal/d<k>/ on a recording with the columns t_s, rpm, T_1_C…T_16_C and
# d1_um…d5_um (the withheld part of the run, or any other), against d<k>/sim.toml (the static
# regression on the 3 best-correlated temperatures fitted on everything shared). Per channel: RMS of
# measured − predicted over every row of the file, and the cut; then the median cut. Two tables:
#   compensation.toml  the deliverable: `retrocomp fit thermal --residual --criterion average`
#                      on sim.toml (docs/diagnose.md "Compensation model");
#   model.toml         `retrocomp diagnose --out`: the physics found (named terms, tested).
# Usage: scripts/fl-thermal-judge.sh WITHHELD.csv   (RETROCOMP=path/to/retrocomp, default target/debug)
set -euo pipefail
csv=${1:?usage: scripts/fl-thermal-judge.sh WITHHELD.csv}
root=$(cd "$(dirname "$0")/.." && pwd)
bin=${RETROCOMP:-$root/target/debug/retrocomp}
models=${FL_THERMAL_MODELS:-$root/deploy/models/fl_thermal}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# col FILE NAME: the values of column NAME, one per line.
col() {
    awk -F, -v name="$2" 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == name) k = i
        if (!k) { print "no column " name " in " FILENAME > "/dev/stderr"; exit 1 }; next }
        { print $k }' "$1"
}

# judge NAME: the table of d<k>/NAME.toml against d<k>/sim.toml, then the median cut.
judge() {
    for k in 1 2 3 4 5; do
        col "$csv" "d${k}_um" >"$tmp/meas"
        for m in "$1" sim; do
            "$bin" eval --model "$models/d$k/$m.toml" --path "$csv" >"$tmp/$m.csv"
            col "$tmp/$m.csv" ez_um >"$tmp/$m"
        done
        paste -d, "$tmp/meas" "$tmp/$1" "$tmp/sim" | awk -F, -v ch="d$k" -v m="$1" '
            { a += ($1 - $2)^2; b += ($1 - $3)^2; n++ }
            END { ra = sqrt(a / n); rb = sqrt(b / n)
                  printf "%s: static %.2f µm, %s %.2f µm, cut %.1f %%\n", ch, rb, m, ra, 100 * (1 - ra / rb) }'
    done | tee "$tmp/table"
    awk '{ sub("%", "", $(NF-1)); print $(NF-1) }' "$tmp/table" | sort -g | sed -n 3p |
        awk -v m="$1" '{ printf "%s: median cut %.1f %%\n", m, $1 }'
}

echo "compensation.toml (the deliverable):"
judge compensation
echo "model.toml (diagnose's found terms):"
judge model
