#!/usr/bin/python3
"""Headless "display" for retrocomp-sim.ini: machine on, home, run part.ngc. At every M0 pause it
writes the HAL pins the closed-loop test checks to pause-K.jsonl (one line every 0.1 s) and waits
for the file resume-K before resuming (and stops if the file abort appears). From start to end a
thread writes the same pins with the wall-clock time to trace.jsonl (one line every 20 ms; the
test compares them with the times it killed and restarted the box). Writes done.json at the end;
LinuxCNC stops when this exits.
Uses Debian's python3 (the linuxcnc and hal modules are not in a venv)."""
import json
import os
import sys
import threading
import time

import hal
import linuxcnc

ini = sys.argv[sys.argv.index("-ini") + 1]
here = os.path.dirname(os.path.abspath(ini))
# hal.get_value needs this process to be a HAL component.
comp = hal.component("rc-drive")
comp.ready()
s = linuxcnc.stat()
c = linuxcnc.command()
PINS = ["axis.%s.%s" % (a, p) for a in "xyz" for p in ("pos-cmd", "eoffset", "eoffset-counts")]
PINS += ["rc-%s-step-max.max" % a for a in "xyz"]
PINS += ["rc-alive", "rc-heartbeat", "rc-trips.count", "rc-watch.restarts", "rc-watch.pass",
         "rc-age-reset.out", "motion.current-vel", "motion.feed-hold", "motion.eoffset-active",
         "motion.eoffset-limited"]


def log(msg):
    with open(os.path.join(here, "drive.log"), "a") as f:
        f.write("%.3f %s\n" % (time.time(), msg))


def aborted():
    # The test writes "abort" when it fails, so LinuxCNC shuts down instead of waiting.
    if os.path.exists(os.path.join(here, "abort")):
        log("aborted")
        sys.exit(3)


def wait(what, pred, timeout_s=300.0):
    t0 = time.time()
    while time.time() - t0 < timeout_s:
        aborted()
        s.poll()
        if pred():
            return
        time.sleep(0.02)
    log("timeout waiting for " + what)
    sys.exit(2)


def value(name):
    try:
        return float(hal.get_value(name))
    except Exception:  # e.g. while mb2hal-watch.py reloads mb2hal
        return None


def pins():
    return {p: value(p) for p in PINS}


def trace():
    with open(os.path.join(here, "trace.jsonl"), "a") as f:
        while True:
            row = pins()
            row["t"] = time.time()
            f.write(json.dumps(row) + "\n")
            f.flush()
            time.sleep(0.02)


threading.Thread(target=trace, daemon=True).start()
c.state(linuxcnc.STATE_ESTOP_RESET)
c.state(linuxcnc.STATE_ON)
wait("machine on", lambda: s.task_state == linuxcnc.STATE_ON)
c.home(-1)
wait("homed", lambda: all(s.homed[i] for i in range(3)))
log("on and homed")
c.mode(linuxcnc.MODE_AUTO)
c.wait_complete()
c.program_open(os.path.join(here, "part.ngc"))
c.auto(linuxcnc.AUTO_RUN, 0)
wait("program start", lambda: s.interp_state != linuxcnc.INTERP_IDLE)
k = 0
# Where the last M0 was handled: on a loaded host this process can sleep through a whole move, so
# "resumed" is "no longer paused OR paused somewhere else", and a pause counts once per place (the
# stops of part.ngc are all distinct; the interpreter's current_line runs ahead of the motion).
paused_at = None


def elsewhere():
    return paused_at is None or max(abs(a - b) for a, b in zip(s.position[:3], paused_at)) > 1.0


while True:
    s.poll()
    if s.interp_state == linuxcnc.INTERP_IDLE and s.exec_state == linuxcnc.EXEC_DONE:
        break
    aborted()
    if s.paused and elsewhere():
        paused_at = tuple(s.position[:3])
        log("pause %d at x=%.4f" % (k, s.position[0]))
        resume = os.path.join(here, "resume-%d" % k)
        with open(os.path.join(here, "pause-%d.jsonl" % k), "a") as f:
            while not os.path.exists(resume):
                aborted()
                f.write(json.dumps(pins()) + "\n")
                f.flush()
                time.sleep(0.1)
        c.auto(linuxcnc.AUTO_RESUME)
        c.wait_complete()
        wait("resume", lambda: not s.paused or elsewhere())
        k += 1
    time.sleep(0.02)
with open(os.path.join(here, "done.json"), "w") as f:
    json.dump({"pauses": k, "pins": pins()}, f)
log("program done after %d pauses" % k)
