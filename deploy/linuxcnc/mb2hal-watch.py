#!/usr/bin/python3
"""Restart mb2hal when the retrocomp box's heartbeat stops (LinuxCNC 2.9's mb2hal never reconnects
once the server has closed the connection: libmodbus leaves the dead socket open without
MODBUS_ERROR_RECOVERY_LINK, so after a box restart every transaction fails until mb2hal restarts).

Loaded from retrocomp.hal: loadusr -Wn rc-watch /usr/bin/python3 mb2hal-watch.py MB2HAL_INI [DEAD_S]
When the signal rc-heartbeat has not changed for DEAD_S seconds (default 3) it unloads mb2hal, loads
it again with the same config and re-links its pins to the kit's signals. The signals keep their last
values meanwhile, and rc-watch.pass (retrocomp.hal's hold stage) is false from before the
unload until the new mb2hal has read the box twice, so the new pins' initial 0 never reaches
LinuxCNC (no step); the box resumes from the held value mb2hal writes back first. Pin
rc-watch.restarts counts the restarts."""
import subprocess
import sys
import time

import hal

ini = sys.argv[1]
dead_s = float(sys.argv[2]) if len(sys.argv) > 2 else 3.0
MARKER = "21930"  # register 12, as in retrocomp.hal and the box's write_marker
NETS = [
    ("rc-x-raw", "mb2hal.rc-in.00.float"),
    ("rc-heartbeat", "mb2hal.rc-in.01.float"),
    ("rc-x-pos-word", "mb2hal.rc-out.00"),
    ("rc-x-held-word", "mb2hal.rc-out.01"),
]

comp = hal.component("rc-watch")
comp.newpin("restarts", hal.HAL_S32, hal.HAL_OUT)
# True: pass mb2hal's counts through (retrocomp.hal's rc-x-hold); false: hold them.
comp.newpin("pass", hal.HAL_BIT, hal.HAL_OUT)
comp["pass"] = True
comp.ready()


def halcmd(*args):
    return subprocess.run(["halcmd"] + list(args), check=False).returncode


last_hb = None
since = time.time()
try:
    while True:
        time.sleep(0.2)
        try:
            hb = hal.get_value("rc-heartbeat")
        except Exception:  # the signal is created after this component (retrocomp.hal)
            since = time.time()
            continue
        now = time.time()
        if hb != last_hb:
            last_hb, since = hb, now
            continue
        if now - since < dead_s:
            continue
        comp["pass"] = False
        time.sleep(0.05)  # let the servo thread take the hold before the pins go
        halcmd("unloadusr", "mb2hal")
        while halcmd("-s", "show", "comp", "mb2hal") == 0 and hal.component_exists("mb2hal"):
            time.sleep(0.1)
        halcmd("loadusr", "-W", "mb2hal", "config=" + ini)
        # Link first, then set the write marker: until then the new mb2hal's writes (pins at 0)
        # carry marker 0 and the box ignores them.
        for sig, pin in NETS:
            halcmd("net", sig, pin)
        halcmd("setp", "mb2hal.rc-out.02", MARKER)
        comp["restarts"] += 1
        # Linked pins start at 0: pass the counts again only after two heartbeat changes (two
        # real reads from the box).
        seen, changes = hal.get_value("rc-heartbeat"), 0
        while changes < 2:
            time.sleep(0.05)
            hb = hal.get_value("rc-heartbeat")
            if hb != seen:
                seen, changes = hb, changes + 1
        comp["pass"] = True
        last_hb, since = seen, time.time()
except KeyboardInterrupt:
    pass
