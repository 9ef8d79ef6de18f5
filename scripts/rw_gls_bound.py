#!/usr/bin/env python3
"""Best-case evidence for a hidden slow effect under random-walk noise (issue 12, hard families).

For each case (`hil-sim gen-cases` output: CASE.csv + CASE.json), the residual r = ex − sim_ex is
the hidden effect plus the family's noise: a Gaussian random walk w plus the 0.05 µm steps of the
recording (white, e). The efficient test for a known effect SHAPE h in that noise is generalised
least squares on the increments: Δr = k·Δh + Δw + Δe, with Cov(Δ) = σw²·I + σe²·(2 on the
diagonal, −1 beside it). σw² and σe² are taken from the increments' variance and lag-1
autocovariance. The shape given to the test is the truth's own (time for `time_drift`; the named
sensor, through its τ for a lag, else smoothed over 120 s so its 0.1 °C steps do not swamp the
increments) — more than `diagnose` knows. The printed z is therefore an upper bound on the evidence
any method has for that term in that recording; `diagnose`'s bar (ΔBIC > 10 and a Holm-corrected
F-test over a few hundred tried terms) needs |z| ≳ 4.3.

With --nulls, each case (meant: the null cases) is scored the other way round: the largest |z|, per
error signal, over a small set of slow shapes (time; every T_*, rpm, aux_V and strain column through
lags of 120, 300, 900 and 1800 s) — how strong a slow term looks in a recording that has none.

Usage: scripts/rw_gls_bound.py [--nulls] DIR CASE [CASE ...]   (needs numpy and scipy: .venv-bench)
"""

import csv
import json
import sys
from pathlib import Path

import numpy as np
import scipy.linalg as sl


def lowpass(v, tau_s, dt_s=1.0):
    a = dt_s / tau_s
    out = np.empty_like(v)
    out[0] = v[0]
    for i in range(1, len(v)):
        out[i] = out[i - 1] + a * (v[i] - out[i - 1])
    return out


def whitener(r):
    """GLS whitening of the increments of r under random walk + white noise (see the top)."""
    d = np.diff(r)
    dc = d - d.mean()
    g0, g1 = np.mean(dc * dc), np.mean(dc[1:] * dc[:-1])
    se2 = max(-g1, 1e-12)
    sw2 = max(g0 - 2.0 * se2, 1e-12)
    n = len(d)
    band = np.zeros((2, n))
    band[0, 1:] = -se2
    band[1, :] = sw2 + 2.0 * se2
    upper = sl.cholesky_banded(band)
    lower = np.vstack([upper[1], np.r_[upper[0, 1:], 0.0]])
    return lambda v: sl.solve_banded((1, 0), lower, v), d


def gls_z(whiten, d, shape):
    """(gain, z) of shape's increments against d's, both whitened."""
    a, b = whiten(d), whiten(np.diff(shape))
    k = (b @ a) / (b @ b)
    res = a - k * b
    s = np.sqrt(res @ res / (len(a) - 1))
    return k, k / (s / np.sqrt(b @ b))


def null_max(case_dir, case):
    rows = list(csv.DictReader(open(case_dir / f"{case}.csv")))
    t_s = np.array([float(x["t_s"]) for x in rows])
    shapes = {"time": t_s / 3600.0}
    for c in rows[0]:
        if c.startswith("T_") or c in ("rpm", "aux_V", "strain_col_ue"):
            v = np.array([float(x[c]) for x in rows])
            for tau in (120.0, 300.0, 900.0, 1800.0):
                shapes[f"{c} lag {tau:.0f} s"] = lowpass(v, tau)
    out = []
    for sig in ("ex", "ey"):
        r = np.array([float(x[f"{sig}_um"]) - float(x[f"sim_{sig}_um"]) for x in rows])
        whiten, d = whitener(r)
        zs = {k: gls_z(whiten, d, s)[1] for k, s in shapes.items() if np.ptp(s) > 0}
        best = max(zs, key=lambda k: abs(zs[k]))
        out.append(f"{sig}_um max |z| {abs(zs[best]):.2f} ({best}, of {len(zs)} shapes)")
    return f"{case}: " + "; ".join(out)


def bound(case_dir, case):
    rows = list(csv.DictReader(open(case_dir / f"{case}.csv")))
    manifest = json.load(open(case_dir / f"{case}.json"))
    hidden = manifest["hidden"][0]
    p = hidden["params"]
    r = np.array([float(x["ex_um"]) - float(x["sim_ex_um"]) for x in rows])
    t_s = np.array([float(x["t_s"]) for x in rows])
    if hidden["effect"] == "time_drift":
        shape, truth = t_s / 3600.0, p["um_per_h"]
    elif "sensor" in p:
        temp = np.array([float(x[p["sensor"]]) for x in rows])
        shape = lowpass(temp, p["tau_s"]) if "tau_s" in p else lowpass(temp, 120.0)
        truth = p["um_per_K"]
    else:
        return f"{case}: {hidden['effect']} is not a slow effect; no bound computed"
    whiten, d = whitener(r)
    k, z = gls_z(whiten, d, shape)
    return (
        f"{case}: {hidden['effect']} effect/noise {manifest['snr']:.2f}, n {len(r)}: "
        f"GLS gain {k:.3f} (truth {truth:.3f}), z {z:+.2f}"
    )


def main():
    args = sys.argv[1:]
    nulls = bool(args) and args[0] == "--nulls"
    args = args[1:] if nulls else args
    if len(args) < 2:
        sys.exit(__doc__)
    case_dir = Path(args[0])
    for case in args[1:]:
        print(null_max(case_dir, case) if nulls else bound(case_dir, case))


if __name__ == "__main__":
    main()
