#!/usr/bin/python3
"""Restart mb2hal when the retrocomp box's heartbeat stops (LinuxCNC 2.9's mb2hal never reconnects
once the server has closed the connection: libmodbus leaves the dead socket open without
MODBUS_ERROR_RECOVERY_LINK, so after a box restart every transaction fails until mb2hal restarts).

Loaded from retrocomp.hal: loadusr -Wn rc-watch /usr/bin/python3 mb2hal-watch.py MB2HAL_INI [DEAD_S]

This script is not the safety stop: retrocomp.hal's box watch (servo thread) holds the feed whenever
the heartbeat is silent for RC_DEAD_S (rc-stale.in0), whatever this script does. This script only brings
the link back, and keeps a re-link from looking like life:

- When the signal rc-heartbeat has not changed for DEAD_S seconds (default 3) it sets rc-watch.pass
  false, unloads mb2hal, loads it again with the same config and re-links every mb2hal pin to the
  signal it was on before (read from halcmd, so every axis the HAL wires is covered), then sets the
  unlinked input pins (the write marker) to their old values. With the box still dead it does this
  again every DEAD_S.
- rc-watch.pass stays false until the new mb2hal has read FORWARD_BEATS heartbeat steps forward
  (+1 … +MAX_STEP, modulo 65536). A re-linked pin jumps once (e.g. 594 → 0) and a dead box never
  steps forward, so neither makes pass true. While pass is false retrocomp.hal holds the counts
  (the new pins' initial 0 never reaches LinuxCNC) and keeps its beat count at 0, so rc-alive needs
  3 more heartbeat changes after pass. rc-watch.restarts counts the restarts."""
import subprocess
import sys
import time

import hal

ini = sys.argv[1]
dead_s = float(sys.argv[2]) if len(sys.argv) > 2 else 3.0
FORWARD_BEATS = 3
MAX_STEP = 100  # heartbeat steps between two mb2hal reads that still count as forward
POLL_S = 0.05

comp = hal.component("rc-watch")
comp.newpin("restarts", hal.HAL_S32, hal.HAL_OUT)
# True: pass mb2hal's counts through (retrocomp.hal's rc-L-hold); false: hold them.
comp.newpin("pass", hal.HAL_BIT, hal.HAL_OUT)
comp["pass"] = True
comp.ready()


def halcmd(*args, out=False):
    # Output is captured only for `show`: a process loadusr starts (mb2hal) inherits halcmd's stdout,
    # and a captured pipe would then never reach end-of-file.
    if out:
        return subprocess.run(["halcmd"] + list(args), check=False, capture_output=True, text=True).stdout
    return subprocess.run(["halcmd"] + list(args), check=False, stdout=subprocess.DEVNULL).returncode


def mb2hal_pins():
    """[(pin, signal or None, direction, value)] of every mb2hal pin, from `halcmd show pin`."""
    pins = []
    for line in halcmd("show", "pin", "mb2hal.", out=True).splitlines():
        f = line.split()
        if len(f) >= 5 and f[4].startswith("mb2hal."):
            sig = f[6] if len(f) >= 7 and f[5] in ("==>", "<==", "<=>") else None
            pins.append((f[4], sig, f[2], f[3]))
    return pins


def heartbeat():
    try:
        return hal.get_value("rc-heartbeat")
    except Exception:  # the signal is created after this component (retrocomp.hal)
        return None


def forward(prev, hb):
    step = (int(hb) - int(prev)) % 65536
    return 0 < step <= MAX_STEP


def restart(pins):
    comp["pass"] = False
    time.sleep(0.05)  # let the servo thread take the hold before the pins go
    halcmd("unloadusr", "mb2hal")
    while hal.component_exists("mb2hal"):
        time.sleep(0.1)
    halcmd("loadusr", "-W", "mb2hal", "config=" + ini)
    # Link first, then set the unlinked inputs (the write marker): until then the new mb2hal's
    # writes (pins at 0) carry marker 0 and the box ignores them.
    for pin, sig, _, _ in pins:
        if sig:
            halcmd("net", sig, pin)
    for pin, sig, direction, value in pins:
        if not sig and direction == "IN":
            halcmd("setp", pin, value)
    comp["restarts"] += 1


pins = []
last_hb, since, beats = None, time.time(), 0
try:
    while True:
        time.sleep(POLL_S)
        hb = heartbeat()
        now = time.time()
        if hb is None:
            since = now
            continue
        if hb != last_hb:
            if not comp["pass"]:
                # Only steps read over the new link count; one that is not forward starts again.
                beats = beats + 1 if last_hb is not None and forward(last_hb, hb) else 0
                if beats >= FORWARD_BEATS:
                    comp["pass"] = True
            last_hb, since = hb, now
            continue
        if now - since < dead_s:
            continue
        # Remember the wiring while mb2hal is loaded (a failed load leaves none to read).
        pins = mb2hal_pins() or pins
        restart(pins)
        last_hb, since, beats = heartbeat(), time.time(), 0
except KeyboardInterrupt:
    pass
