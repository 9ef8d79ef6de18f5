"""LinuxCNC HAL peer: replays the quadrature sink's edge trace into LinuxCNC's `encoder` component.

Usage (from a .hal file, after `loadrt encoder num_chan=N` on a thread):
    loadusr -Wn replay /usr/bin/python3 hal_encoder_replay.py TRACE AXES OUT
TRACE: the sink's CSV (t_ns,axis,a,b,source); AXES: comma-separated axis names, channel k of the
encoder per name; OUT: JSON written at the end, per axis {"counts": encoder.k.counts, "edges": rows
replayed, "unseen": edges after which encoder.k.rawcounts did not move within 5 s}.
Pins: replay.a<k>/b<k> (out, to encoder.k.phase-A/B), replay.raw<k>/counts<k> (in, from the
encoder), replay.reset<k> (out, to encoder.k.reset), replay.go (in: set after `start`).
The encoder samples the lines on its thread; one line changes per row, and the next row is only
driven once the encoder has counted the previous one, so its count is LinuxCNC's, row for row.
"""
import csv
import json
import sys
import time

import hal

trace, axes, out = sys.argv[1], sys.argv[2].split(","), sys.argv[3]
c = hal.component("replay")
for k in range(len(axes)):
    c.newpin(f"a{k}", hal.HAL_BIT, hal.HAL_OUT)
    c.newpin(f"b{k}", hal.HAL_BIT, hal.HAL_OUT)
    c.newpin(f"reset{k}", hal.HAL_BIT, hal.HAL_OUT)
    c.newpin(f"raw{k}", hal.HAL_S32, hal.HAL_IN)
    c.newpin(f"counts{k}", hal.HAL_S32, hal.HAL_IN)
c.newpin("go", hal.HAL_BIT, hal.HAL_IN)
c.ready()
while not c["go"]:
    time.sleep(0.01)

with open(trace, newline="") as f:
    rows = list(csv.DictReader(f))
index = {name: k for k, name in enumerate(axes)}
SETTLE_S = 0.05

# The levels each thread took the lines at, then zero the counters there.
for r in rows:
    if r["source"] == "start":
        k = index[r["axis"]]
        c[f"a{k}"], c[f"b{k}"] = r["a"] == "1", r["b"] == "1"
time.sleep(SETTLE_S)
for k in range(len(axes)):
    c[f"reset{k}"] = True
time.sleep(SETTLE_S)
for k in range(len(axes)):
    c[f"reset{k}"] = False
time.sleep(SETTLE_S)

edges = [0] * len(axes)
unseen = [0] * len(axes)
for r in rows:
    if r["source"] == "start":
        continue
    k = index[r["axis"]]
    before = c[f"raw{k}"]
    c[f"a{k}"], c[f"b{k}"] = r["a"] == "1", r["b"] == "1"
    edges[k] += 1
    deadline = time.monotonic() + 5.0
    while c[f"raw{k}"] == before:
        if time.monotonic() > deadline:
            unseen[k] += 1
            break
        time.sleep(0.0002)
time.sleep(SETTLE_S)
result = {name: {"counts": c[f"counts{k}"], "edges": edges[k], "unseen": unseen[k]}
          for name, k in index.items()}
with open(out, "w") as f:
    json.dump(result, f)
