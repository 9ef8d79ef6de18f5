#!/usr/bin/env python3
"""PySINDy side by side with `retrocomp diagnose` on the concealed-effect cases (issue 7 item 8).

Usage:
    python3 -m venv .venv && .venv/bin/pip install -r scripts/requirements-bench.txt
    cargo build --release --workspace
    target/release/hil-sim gen-cases --seed 1 --count 100 --out /tmp/cases
    .venv/bin/python scripts/pysindy_compare.py --cases /tmp/cases [--retrocomp target/release/retrocomp]

What PySINDy gets: the SAME residual r = e − sim per error signal and an equivalent candidate
library built from the same context features (DESIGN §5 effect ids; nonlinear parameters on fixed
grids: thermal τ, cyclic period, reversal-spike decay, because SINDy is linear in its library),
columns standardised, fitted with PySINDy's STLSQ (sequentially thresholded least squares; its
`threshold` on standardised coefficients, in units of the residual's standard deviation) and the
final unregularised refit. A term that survives names its effect id; no survivor = `none`.
Scored like retrocomp: recall (right effect and axis) on identifiable cases with effect/noise ≥ 1,
false-positive rate on nulls, wall-clock runtime. retrocomp runs as `retrocomp diagnose-bench`.
"""

import argparse
import csv
import glob
import json
import math
import os
import re
import subprocess
import sys
import time

try:
    import numpy as np
    import pysindy as ps
except ImportError as e:  # the script is not part of CI; say how to get the peers
    sys.exit(f"missing {e.name}: pip install -r scripts/requirements-bench.txt")


def read_recording(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    names = rows[0]
    data = np.array(rows[1:], dtype=float)
    return {n: data[:, i] for i, n in enumerate(names)}


def lowpass(t, u, tau):
    y = np.empty_like(u)
    acc = u[0]
    y[0] = acc
    a = 1.0 - np.exp(-np.diff(t) / tau)
    for i in range(1, len(u)):
        acc += a[i - 1] * (u[i - 1] - acc)
        y[i] = acc
    return y


def axis_features(t, x):
    dx = np.diff(x, prepend=x[0])
    dt = np.diff(t, prepend=t[0] - 1.0)
    v = np.where(dt > 0, dx / np.where(dt > 0, dt, 1.0), 0.0)
    d = np.zeros_like(x)
    since = np.zeros_like(x)
    cur, s = 0.0, 1e9
    for i in range(len(x)):
        if abs(dx[i]) > 1e-4:
            sg = math.copysign(1.0, dx[i])
            if cur != 0.0 and sg != cur:
                s = 0.0
            cur = sg
        s += abs(dx[i])
        d[i], since[i] = cur, s
    first = np.flatnonzero(d != 0)
    if len(first):
        d[: first[0]] = d[first[0]]
    return v, d, since


def library(rec, axis):
    """(effect_id, column) pairs equivalent to retrocomp's candidate library for signal e<axis>."""
    t = rec["t_s"]
    cols = []
    pos = rec.get(f"{axis}_mm")
    temps = [n for n in rec if n.startswith("T_") and n.endswith("_C")]
    loads = [n for n in rec if (n.startswith("F_") and n.endswith("_N")) or (n.startswith("strain_") and n.endswith("_ue"))]
    if pos is not None and np.ptp(pos) > 0:
        v, d, since = axis_features(t, pos)
        lo, hi = pos.min(), pos.max()
        travel = hi - lo
        cols.append(("scale_error", pos))
        cols.append(("backlash", d / 2))
        for k in range(4):
            z = (pos >= lo + travel * k / 4) & (pos <= lo + travel * (k + 1) / 4)
            cols.append(("reversal_profile", d / 2 * z))
        for p in np.geomspace(max(1.0, travel / 200), travel / 1.5, 60):
            cols.append(("cyclic_error", np.sin(2 * np.pi * pos / p)))
            cols.append(("cyclic_error", np.cos(2 * np.pi * pos / p)))
        if "tool_mm" in rec and np.ptp(rec["tool_mm"]) > 0:
            cols.append(("abbe", pos * rec["tool_mm"]))
        cols.append(("servo_lag", -v))
        for dec in np.geomspace(travel / 500, travel / 5, 8):
            cols.append(("reversal_spike", d * np.exp(-since / dec)))
        for n in temps:
            cols.append(("thermal_expansion", pos * (rec[n] - rec[n][0])))
    for o in "xyz":
        if o != axis and f"{o}_mm" in rec and np.ptp(rec[f"{o}_mm"]) > 0:
            q = rec[f"{o}_mm"]
            cols.append(("squareness", q))
            cols.append(("straightness", (q - 0.5 * (q.min() + q.max())) ** 2))
    for n in temps:
        if np.ptp(rec[n]) > 0:
            cols.append(("thermal_drift", rec[n] - rec[n][0]))
            for tau in np.geomspace(30, max(60, (t[-1] - t[0]) / 2), 10):
                cols.append(("thermal_lag", lowpass(t, rec[n], tau) - rec[n][0]))
    for n in loads:
        if np.ptp(rec[n]) > 0:
            cols.append(("force_deflection", rec[n]))
    cols.append(("time_drift", t / 3600))
    return cols


def sindy_case(csv_path, threshold):
    rec = read_recording(csv_path)
    found = []
    for sig in [s for s in ("ex_um", "ey_um", "ez_um") if s in rec]:
        r = rec[sig] - rec[f"sim_{sig}"]
        y = r - r.mean()
        if y.std() == 0:
            continue
        lib = library(rec, sig[1])
        ids = [c[0] for c in lib]
        X = np.column_stack([c[1] for c in lib])
        X = X - X.mean(axis=0)
        sd = X.std(axis=0)
        keep = sd > 0
        X = X[:, keep] / sd[keep]
        ids = [i for i, k in zip(ids, keep) if k]
        opt = ps.STLSQ(threshold=threshold * y.std(), alpha=1e-6, unbias=True)
        opt.fit(X, (y / 1.0).reshape(-1, 1))
        coef = np.asarray(opt.coef_).ravel()
        for eff in sorted({ids[j] for j in np.flatnonzero(coef != 0)}):
            found.append((eff, sig[1]))
    return found


def score(cases_dir, threshold):
    recall_hits = recall_total = nulls = fps = 0
    start = time.perf_counter()
    for csv_path in sorted(glob.glob(os.path.join(cases_dir, "case_*.csv"))):
        m = json.load(open(csv_path[:-4] + ".json"))
        found = sindy_case(csv_path, threshold)
        if not m["hidden"]:
            nulls += 1
            fps += bool(found)
        elif m["identifiable"] and (m["snr"] or 0) >= 1.0:
            for h in m["hidden"]:
                recall_total += 1
                recall_hits += (h["effect"], h["axis"]) in found
    elapsed = time.perf_counter() - start
    return recall_hits / max(recall_total, 1), fps / max(nulls, 1), elapsed, recall_total, nulls


def retrocomp_bench(binary, cases_dir):
    start = time.perf_counter()
    out = subprocess.run([binary, "diagnose-bench", "--cases", cases_dir], capture_output=True, text=True, check=True).stdout
    elapsed = time.perf_counter() - start
    grab = lambda label: float(re.search(re.escape(label) + r"[^|]*\| ([0-9.]+)", out).group(1))
    return grab("recall (right effect and axis)"), grab("false-positive rate on"), elapsed, out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", required=True)
    ap.add_argument("--retrocomp", default="target/release/retrocomp")
    ap.add_argument("--thresholds", default="0.05,0.1,0.2", help="STLSQ thresholds (× residual std) to report")
    a = ap.parse_args()
    r_rec, r_fpr, r_time, table = retrocomp_bench(a.retrocomp, a.cases)
    print(f"pysindy {ps.__version__}; cases in {a.cases}\n")
    print("| method | recall (effect/noise ≥ 1) | FPR on nulls | runtime (s) |")
    print("|---|---|---|---|")
    print(f"| retrocomp diagnose | {r_rec:.3f} | {r_fpr:.3f} | {r_time:.1f} |")
    for th in [float(s) for s in a.thresholds.split(",")]:
        rec, fpr, el, n_eff, n_null = score(a.cases, th)
        print(f"| PySINDy STLSQ (threshold {th:g}·σ_r) | {rec:.3f} | {fpr:.3f} | {el:.1f} |")
    print(f"\n({n_eff} hidden effects scored, {n_null} nulls)\n\nretrocomp diagnose-bench output:\n{table}")


if __name__ == "__main__":
    main()
