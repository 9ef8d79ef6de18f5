#!/usr/bin/env python3
"""PySINDy side by side with `retrocomp diagnose` on the concealed-effect cases (issue 12 item 9).

Usage (a separate, optional venv: not part of CI):
    python3 -m venv .venv-bench && .venv-bench/bin/pip install -r scripts/requirements-bench.txt
    cargo build --release -p retrocomp -p hil-sim
    target/release/hil-sim gen-cases --seed 1 --count 100 --out /tmp/cases
    target/release/hil-sim gen-cases --seed 1 --count 20 --families hard --out /tmp/cases
    .venv-bench/bin/python scripts/pysindy_compare.py --cases /tmp/cases [--retrocomp target/release/retrocomp]

What PySINDy gets: the SAME residual r = e − sim per error signal and an equivalent candidate
library built from the same context features (docs/diagnose-json.md effect ids; nonlinear parameters on fixed
grids — thermal τ, cyclic period, reversal-spike decay — because SINDy is linear in its library;
`rpm` enters as a heat driver through the same τ grid as the temperatures, which retrocomp's
library did not have when this was written), columns standardised, fitted with PySINDy's STLSQ
(sequentially thresholded ridge regression) and its final unbiased refit. A term that survives
names its effect id; no survivor = `none`.

Its strongest honest setup, not a straw man: the ridge penalty is scaled to n (alpha = a·n on
standardised columns, a ∈ --alphas) and the threshold (× the residual's standard deviation) is
swept over --thresholds. Per case and signal, (a, threshold) — including the empty model — is
chosen WITHOUT the truth, by two rules reported side by side:
  * CV: leave-one-`run`-out cross-validated squared error (the same blocks retrocomp validates on);
  * BIC: n·ln(RSS/n) + k·ln(n) of the refit on all rows.
The fixed-setting sweep (every (a, threshold) applied to every case) is printed too, so the
trade-off is visible. Scored like retrocomp: recall (right effect and axis) on identifiable cases
with effect/noise ≥ 1, false-positive rate on nulls, per family and overall; wall-clock runtime of
PySINDy's whole sweep + selection (all rules share the fits) and of `retrocomp diagnose-bench`.
"""

import argparse
import csv
import glob
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
import warnings
from collections import defaultdict

# One BLAS thread, like retrocomp (single-threaded): fair runtimes, and no oversubscription.
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

try:
    import numpy as np
    import pysindy as ps
    from scipy.signal import lfilter
except ImportError as e:  # the script is not part of CI; say how to get the peers
    sys.exit(f"missing {e.name}: pip install -r scripts/requirements-bench.txt")

# STLSQ warns each time a threshold removes every term: that is the empty model, a legal answer.
warnings.filterwarnings("ignore", message="Sparsity parameter is too big")


def read_recording(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    names = rows[0]
    data = np.array(rows[1:], dtype=float)
    return {n: data[:, i] for i, n in enumerate(names)}


def lowpass(t, u, tau):
    """Same filter as retrocomp's features::lowpass (held input, start at u[0]); constant Δt assumed."""
    a = 1.0 - np.exp(-(t[1] - t[0]) / tau)
    y, _ = lfilter([0.0, a], [1.0, -(1.0 - a)], u, zi=[u[0]])
    return y


def axis_features(t, x):
    """Velocity, latched direction and distance since reversal, as retrocomp's features::latch:
    velocity is the central difference of the commanded position, zero at every standstill row (a
    row at the position of a neighbour), so a step between two dwell readings gives no velocity."""
    dx = np.diff(x, prepend=x[0])
    n = len(x)
    lo, hi = np.maximum(np.arange(n) - 1, 0), np.minimum(np.arange(n) + 1, n - 1)
    db = 1e-4  # approach::RECORDED_DEADBAND_MM
    idx = np.arange(n)
    still = ((lo < idx) & (np.abs(x[lo] - x) <= db)) | ((hi > idx) & (np.abs(x[hi] - x) <= db))
    dt = t[hi] - t[lo]
    v = np.where(~still & (dt > 0), (x[hi] - x[lo]) / np.where(dt > 0, dt, 1.0), 0.0)
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
    drivers = temps + (["rpm"] if "rpm" in rec else [])
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
            cols.append((("thermal_expansion", n), pos * (rec[n] - rec[n][0])))
    for o in "xyz":
        if o != axis and f"{o}_mm" in rec and np.ptp(rec[f"{o}_mm"]) > 0:
            q = rec[f"{o}_mm"]
            cols.append(("squareness", q))
            cols.append(("straightness", (q - 0.5 * (q.min() + q.max())) ** 2))
    for n in drivers:
        if np.ptp(rec[n]) > 0:
            cols.append((("thermal_drift", n), rec[n] - rec[n][0]))
            for tau in np.geomspace(30, max(60, (t[-1] - t[0]) / 2), 10):
                cols.append((("thermal_lag", n), lowpass(t, rec[n], tau) - rec[n][0]))
    for n in loads:
        if np.ptp(rec[n]) > 0:
            cols.append(("force_deflection", rec[n]))
    cols.append(("time_drift", t / 3600))
    return cols


class Compressed:
    """X = QR: STLSQ sees X only through XᵀX = RᵀR and Xᵀy = RᵀQᵀy (its ridge solves and the
    unbiased least-squares refit), so fitting it on (R, Qᵀy) gives exactly the coefficients it
    gives on (X, y) — with p rows instead of n (≈ 20× faster here). Used for speed only."""

    def __init__(self, X, y):
        self.Q, self.R = np.linalg.qr(X, mode="reduced")
        self.qty = self.Q.T @ y

    def stlsq(self, alpha, threshold):
        """STLSQ on centred data; returns the coefficient vector (zeros = dropped terms)."""
        opt = ps.STLSQ(threshold=threshold, alpha=alpha, unbias=True)
        opt.fit(self.R, self.qty.reshape(-1, 1))
        return np.asarray(opt.coef_).ravel()


def sweep_signal(rec, sig, alphas, thresholds):
    """Every (a, threshold) fitted on all rows and leave-one-run-out. Returns
    {(a, th): (effects found, BIC, CV SSE)} and the empty model's (BIC, CV SSE)."""
    r = rec[sig] - rec[f"sim_{sig}"]
    lib = library(rec, sig[1])
    # (effect id, driver): thermal terms name their sensor (or rpm), the others no driver.
    ids = [c[0] if isinstance(c[0], tuple) else (c[0], None) for c in lib]
    X = np.column_stack([c[1] for c in lib])
    sd = X.std(axis=0)
    keep = sd > 0
    X = X[:, keep]
    ids = [i for i, k in zip(ids, keep) if k]
    n = len(r)
    run = rec["run"] if "run" in rec else np.floor(np.arange(n) * 5 / n)
    folds = [run == b for b in np.unique(run)]
    sigma = r.std()
    # Full-data standardisation for the all-rows fit; per-fold standardisation on training rows.
    def prep(rows):
        mu, s = X[rows].mean(axis=0), X[rows].std(axis=0)
        s = np.where(s > 0, s, 1.0)
        return mu, s, r[rows].mean()
    all_rows = np.ones(n, dtype=bool)
    mu, s, ym = prep(all_rows)
    Xs, ys = (X - mu) / s, r - ym
    null_rss = float(ys @ ys)
    null_cv = 0.0
    full = Compressed(Xs, ys)
    fold_prep = []
    for f in folds:
        tr = ~f
        fmu, fs, fym = prep(tr)
        null_cv += float(((r[f] - fym) ** 2).sum())
        fold_prep.append((tr, f, fmu, fs, fym, Compressed((X[tr] - fmu) / fs, r[tr] - fym)))
    out = {}
    for a in alphas:
        for c in thresholds:
            if sigma == 0:
                out[(a, c)] = (set(), math.inf, math.inf)
                continue
            w = full.stlsq(a * n, c * sigma)
            nz = np.flatnonzero(w)
            rss = float(((ys - Xs @ w) ** 2).sum())
            bic = n * math.log(max(rss, 1e-300) / n) + len(nz) * math.log(n)
            cv = 0.0
            for tr, f, fmu, fs, fym, comp in fold_prep:
                wf = comp.stlsq(a * tr.sum(), c * sigma)
                cv += float(((r[f] - fym - ((X[f] - fmu) / fs) @ wf) ** 2).sum())
            out[(a, c)] = ({ids[j] for j in nz}, bic, cv)
    null_bic = n * math.log(max(null_rss, 1e-300) / n)
    return out, (null_bic, null_cv)


def pick(sweep, null, rule):
    """The setting (or the empty model) with the smallest criterion: 0 = BIC, 1 = CV SSE."""
    k = 0 if rule == "bic" else 1
    best, best_v = set(), null[k]
    for found, *crit in sweep.values():
        if crit[k] < best_v:
            best, best_v = found, crit[k]
    return best


def run_pysindy(paths, alphas, thresholds):
    """Per case: the manifest, per rule/setting the set of (effect, axis) found, and the case's
    wall-clock time (reading the CSV, building the library, the whole sweep and both selections)."""
    results = []
    start = time.perf_counter()
    for p in paths:
        t0, c0 = time.perf_counter(), time.process_time()
        m = json.load(open(p[:-4] + ".json"))
        rec = read_recording(p)
        found = defaultdict(set)
        for sig in [s for s in ("ex_um", "ey_um", "ez_um") if s in rec and f"sim_{s}" in rec]:
            sweep, null = sweep_signal(rec, sig, alphas, thresholds)
            for rule in ("cv", "bic"):
                found[rule] |= {(e, sig[1], d) for e, d in pick(sweep, null, rule)}
            for key, (eff, _, _) in sweep.items():
                found[key] |= {(e, sig[1], d) for e, d in eff}
        m["_pysindy_s"] = time.perf_counter() - t0
        m["_pysindy_cpu_s"] = time.process_time() - c0
        results.append((m, found))
        short = lambda f: sorted({(e, ax) for e, ax, _ in f})
        print(f"{m['case']}: cv {short(found['cv'])} bic {short(found['bic'])}", file=sys.stderr, flush=True)
    return results, time.perf_counter() - start


def names(h, e, ax, d):
    """Scored like retrocomp (scoring.rs `names`): effect id and axis; a heat source seen only
    through rpm must be named with rpm as its driver."""
    rpm_truth = h["params"].get("sensor") == "rpm"
    return e == h["effect"] and ax == h["axis"] and (not rpm_truth or d == "rpm")


def score(results, key, families=None):
    """Recall, FPR, effects scored, nulls, and the mean number of spurious (effect, axis) pairs
    named per scored effect case (what a method that names everything pays for its recall), over
    the cases of `families` (None: all)."""
    hits = total = nulls = fps = spurious = cases = 0
    for m, found in results:
        if families is not None and m.get("family", "standard") not in families:
            continue
        f = found[key]
        if not m["hidden"]:
            nulls += 1
            fps += bool(f)
        elif m["identifiable"] and (m["snr"] or 0) >= 1.0:
            cases += 1
            for h in m["hidden"]:
                total += 1
                hits += any(names(h, *x) for x in f)
            spurious += len({(e, ax) for e, ax, d in f if not any(names(h, e, ax, d) for h in m["hidden"])})
    return hits / max(total, 1), fps / max(nulls, 1), total, nulls, spurious / max(cases, 1)


def retrocomp_spurious(cases, families):
    cs = [c for c in cases if c["n_hidden"] > 0 and c["identifiable"] and c["snr"] is not None and c["snr"] >= 1.0
          and c["family"] in families]
    return sum(c["spurious"] for c in cs) / max(len(cs), 1)


def family_of(csv_path):
    return json.load(open(csv_path[:-4] + ".json")).get("family", "standard")


def retrocomp_bench(binary, paths):
    """`retrocomp diagnose-bench --json` once per family (a directory of links to that family's
    case pairs), so each family has its own time. Returns {family: (summary, (wall_s, cpu_s))}
    and the per-case scores of every family. CPU time (user + system of the child) is the figure
    that compares on a loaded machine; wall time there is mostly waiting for a core."""
    by_family = defaultdict(list)
    for p in paths:
        by_family[family_of(p)].append(p)
    out, cases = {}, []
    for fam, ps_ in sorted(by_family.items()):
        with tempfile.TemporaryDirectory(prefix=f"pysindy_cmp_{fam}_") as d:
            for p in ps_:
                for q in (p, p[:-4] + ".json"):
                    os.symlink(os.path.abspath(q), os.path.join(d, os.path.basename(q)))
            start, ru0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
            res = subprocess.run([binary, "diagnose-bench", "--cases", d, "--json"], capture_output=True, text=True, check=True).stdout
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            dt = (time.perf_counter() - start, ru1.ru_utime - ru0.ru_utime + ru1.ru_stime - ru0.ru_stime)
        bench = json.loads(res)
        out[fam] = (bench["overall"], dt)
        cases.extend(bench["cases"])
        print(f"retrocomp {fam}: {len(ps_)} cases in {dt[0]:.1f} s wall, {dt[1]:.1f} s CPU", file=sys.stderr, flush=True)
    return out, cases


def pooled(summaries):
    """Recall and FPR over several families' summaries (recall = hits / effects scored and
    FPR = false alarms / nulls, so the pooled ratios are the count-weighted means)."""
    eff = sum(s["effects_scored"] for s in summaries)
    nul = sum(s["nulls"] for s in summaries)
    # A family with no nulls (or no scored effect) has a NaN ratio, serialised as null.
    rec = sum((s["recall"] or 0.0) * s["effects_scored"] for s in summaries) / max(eff, 1)
    fpr = sum((s["fpr"] or 0.0) * s["nulls"] for s in summaries) / max(nul, 1)
    return {"recall": rec, "fpr": fpr, "effects_scored": eff, "nulls": nul}


def pysindy_time(results, family=None):
    """(wall, CPU) seconds of PySINDy's cases of `family` (None: all)."""
    ms = [m for m, _ in results if family is None or m.get("family", "standard") == family]
    return sum(m["_pysindy_s"] for m in ms), sum(m["_pysindy_cpu_s"] for m in ms)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", required=True)
    ap.add_argument("--retrocomp", default="target/release/retrocomp")
    ap.add_argument("--alphas", default="0.01,0.1", help="ridge alpha / n on standardised columns")
    ap.add_argument("--thresholds", default="0.05,0.1,0.2,0.5,1.0", help="STLSQ thresholds (× residual std)")
    a = ap.parse_args()
    alphas = [float(s) for s in a.alphas.split(",")]
    thresholds = [float(s) for s in a.thresholds.split(",")]
    paths = sorted(glob.glob(os.path.join(a.cases, "*.csv")))
    paths = [p for p in paths if os.path.exists(p[:-4] + ".json")]
    rc_families, rc_cases = retrocomp_bench(a.retrocomp, paths)
    r_time = sum(dt[0] for _, dt in rc_families.values())
    r_cpu = sum(dt[1] for _, dt in rc_families.values())
    results, s_time = run_pysindy(paths, alphas, thresholds)
    families = sorted({m.get("family", "standard") for m, _ in results}, key=lambda f: (f != "standard", f))
    hard = [f for f in families if f != "standard"]
    n_cases = lambda fams: sum(m.get("family", "standard") in fams for m, _ in results)
    print(f"pysindy {ps.__version__}; {len(paths)} cases in {a.cases}; alphas {alphas} (× n), thresholds {thresholds} (× σ_r)\n")
    print("| family | method | recall (effect/noise ≥ 1) | FPR on nulls | spurious terms per effect case | effects / nulls | CPU time (s) | wall time (s) |")
    print("|---|---|---|---|---|---|---|---|")
    groups = [(f, [f]) for f in families] + ([("hard families", hard)] if hard else []) + [("all", families)]
    for name, fams in groups:
        rb = pooled([rc_families[f][0] for f in fams if f in rc_families])
        rt = sum(rc_families[f][1][0] for f in fams if f in rc_families)
        rc = sum(rc_families[f][1][1] for f in fams if f in rc_families)
        print(f"| {name} | retrocomp diagnose | {rb['recall']:.3f} | {rb['fpr']:.3f} | {retrocomp_spurious(rc_cases, fams):.2f} | {rb['effects_scored']} / {rb['nulls']} | {rc:.1f} | {rt:.1f} |")
        st = sum(pysindy_time(results, f)[0] for f in fams)
        sc = sum(pysindy_time(results, f)[1] for f in fams)
        for rule, label in (("cv", "PySINDy ridge STLSQ, (a, threshold) by leave-one-run-out CV"), ("bic", "PySINDy ridge STLSQ, (a, threshold) by BIC")):
            rec, fpr, tot, nul, spu = score(results, rule, fams)
            # Both rules share the same fits: the time is the sweep's, once.
            print(f"| {name} | {label} | {rec:.3f} | {fpr:.3f} | {spu:.2f} | {tot} / {nul} | {sc:.1f} (shared) | {st:.1f} (shared) |")
    p_cpu = pysindy_time(results)[1]
    print(f"\nruntime ({n_cases(families)} cases; CPU / wall): retrocomp diagnose-bench {r_cpu:.1f} / {r_time:.1f} s (incl. reading and scoring); PySINDy sweep + both selections {p_cpu:.1f} / {s_time:.1f} s (one BLAS thread)\n")
    print("Fixed-setting sweep (one (a, threshold) for every case; all families):\n")
    print("| a (alpha / n) | threshold (× σ_r) | recall | FPR | spurious per effect case |")
    print("|---|---|---|---|---|")
    for al in alphas:
        for th in thresholds:
            rec, fpr, _, _, spu = score(results, (al, th))
            print(f"| {al:g} | {th:g} | {rec:.3f} | {fpr:.3f} | {spu:.2f} |")


if __name__ == "__main__":
    main()
