#!/usr/bin/env python3
"""`retrocomp eval` beside pandas + pyarrow doing the same job, on one recording of N rows.

The job: read a thermal recording (t_s, rpm, T_1_C…T_16_C, d1…d5), evaluate the thermal-only model
benches/data/eval_thermal_model.toml (a static ΔT polynomial on three sensors plus one sensor read
through a first-order lag, both on EZZ), and write every input column, ex/ey/ez_um, the per-term
columns and `flags`. pandas side: `read_csv(engine="pyarrow")`, the model vectorised in numpy (the lag
as an exact-exponential recursion with scipy.signal.lfilter, uniform Δt), `pyarrow.csv.write_csv` (the
fastest writer pandas has at hand). Both outputs are compared column by column (≤ 1e-5 µm), so the
two really computed the same thing.

    python3 -m venv .venv-bench && .venv-bench/bin/pip install -r scripts/requirements-bench.txt
    cargo build --release --bin retrocomp
    .venv-bench/bin/python scripts/eval_vs_pandas.py --rows 1000000 [--retrocomp target/release/retrocomp]

Prints wall time, CPU time and peak RSS of each side (retrocomp's from GNU time, `/usr/bin/time`,
Debian package `time`; pandas' from this process's own getrusage, pyarrow's threads included). On a
loaded machine compare CPU times: wall times then say more about the load than about the programs.
retrocomp's stdout is the output file itself (as `> out.csv`), or with --pipe a pipe into `cat`. Tiles tests/data/fl_thermal/fl_thermal_dev.csv
(MIT, see its LICENSE) with time continuing, so the recording is real data repeated.
"""
import argparse, os, resource, subprocess, sys, time, tomllib

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pacsv
from scipy.signal import lfilter

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MODEL = os.path.join(REPO, "benches/data/eval_thermal_model.toml")
SOURCE = os.path.join(REPO, "tests/data/fl_thermal/fl_thermal_dev.csv")


def make_recording(path, rows):
    src = pd.read_csv(SOURCE, engine="pyarrow")
    reps = -(-rows // len(src))
    dt = float(src.t_s.iloc[1] - src.t_s.iloc[0])
    big = pd.concat([src] * reps, ignore_index=True).iloc[:rows].copy()
    big["t_s"] = np.arange(rows) * dt
    pacsv.write_csv(pa.Table.from_pandas(big, preserve_index=False), path)


def pandas_eval(inp, out):
    m = tomllib.load(open(MODEL, "rb"))
    sensors = {s["name"]: s for s in m["sensors"]}
    df = pd.read_csv(inp, engine="pyarrow")
    n = len(df)
    total = np.zeros(n)
    terms = {}
    for th in m["thermal"]:
        assert th["target"] == "EZZ" and th["kind"] == "polynomial_dt", th
        e = np.full(n, th["e0_um"])
        for name, b in zip(th["sensors"], th["b_um_per_K"]):
            s = sensors[name]
            t = df[f"T_{name}_C"].to_numpy()
            if "tau_s" in s:
                dt = df.t_s.iloc[1] - df.t_s.iloc[0]
                a = 1.0 - np.exp(-dt / s["tau_s"])
                # y[k] = y[k-1] + a (x[k] - y[k-1]), y[0] = x[0]
                t = np.concatenate([[t[0]], lfilter([a], [1.0, a - 1.0], t[1:], zi=[(1 - a) * t[0]])[0]])
            e += b * (t - s["reference_C"])
        terms[th["name"]] = e
        total += e
    res = df.copy()
    res["ex_um"] = 0.0
    res["ey_um"] = 0.0
    res["ez_um"] = total
    for name, e in terms.items():
        res[f"term_{name}_ex_um"] = 0.0
        res[f"term_{name}_ey_um"] = 0.0
        res[f"term_{name}_ez_um"] = e
    # The exact chain's remainder over the first-order sum: 0 for a model of translations only.
    for d in ("ex", "ey", "ez"):
        res[f"term_higher_order_{d}_um"] = 0.0
    res["flags"] = ""
    pacsv.write_csv(pa.Table.from_pandas(res, preserve_index=False), out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--retrocomp", default=os.path.join(REPO, "target/release/retrocomp"))
    ap.add_argument("--dir", default="/tmp/eval_vs_pandas")
    ap.add_argument("--pipe", action="store_true",
                    help="retrocomp's stdout into a pipe (`| cat > file`) instead of the file itself: "
                         "eval then spools its output (memory, then a temporary file) until every row was good")
    a = ap.parse_args()
    os.makedirs(a.dir, exist_ok=True)
    inp = os.path.join(a.dir, f"rec_{a.rows}.csv")
    if not os.path.exists(inp):
        make_recording(inp, a.rows)
    rc_out, pd_out = os.path.join(a.dir, "retrocomp.csv"), os.path.join(a.dir, "pandas.csv")

    # GNU time reports the child's own peak RSS and CPU; spawned from this (large) Python process
    # directly, the child's ru_maxrss would include Python's pages (vfork/exec keeps the high-water).
    # Each side writes a fresh file: the last run's ≈ 290 MB output is removed before the clock starts,
    # else truncating it (and ext4's flush on close of a truncated-and-rewritten file) is timed too.
    for old in (rc_out, pd_out):
        if os.path.exists(old):
            os.remove(old)
    t0 = time.perf_counter()
    timed = ["/usr/bin/time", "-f", "%M %U %S", a.retrocomp, "eval", "--model", MODEL, "--path", inp]
    if a.pipe:
        p = subprocess.run(["sh", "-c", '"$@" | cat > "$0"', rc_out, *timed],
                           stderr=subprocess.PIPE, check=True, text=True)
    else:
        with open(rc_out, "wb") as f:
            p = subprocess.run(timed, stdout=f, stderr=subprocess.PIPE, check=True, text=True)
    rc_s = time.perf_counter() - t0
    kb, u, sy = p.stderr.strip().splitlines()[-1].split()
    rc_rss, rc_cpu = int(kb) / 1024, float(u) + float(sy)

    r0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    pandas_eval(inp, pd_out)
    pd_s = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    pd_cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    pd_rss = r1.ru_maxrss / 1024

    r = pd.read_csv(rc_out, engine="pyarrow")
    p = pd.read_csv(pd_out, engine="pyarrow")
    assert list(r.columns) == list(p.columns), (list(r.columns), list(p.columns))
    worst = max(float(np.max(np.abs(r[c].to_numpy() - p[c].to_numpy())))
                for c in r.columns if c.endswith("_um") and c.startswith(("e", "term_")))
    assert worst <= 1e-5, f"outputs differ by {worst} µm"
    print(f"rows {a.rows}: retrocomp eval{' (into a pipe)' if a.pipe else ''} {rc_s:.2f} s wall, {rc_cpu:.2f} s CPU, peak RSS {rc_rss:.1f} MB; "
          f"pandas+pyarrow {pd_s:.2f} s wall, {pd_cpu:.2f} s CPU, peak RSS {pd_rss:.0f} MB (whole process); "
          f"speed-up {pd_s / rc_s:.1f}× wall, {pd_cpu / rc_cpu:.1f}× CPU; outputs agree to {worst:.1e} µm")


if __name__ == "__main__":
    sys.exit(main())
