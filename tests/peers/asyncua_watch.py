"""asyncua (pinned in scripts/setup-peers.sh): hold ONE session and ONE subscription to the box's
cycle counter (`Machines/<box>/Monitoring/Compensation/Cycles`) until the file STOP_FILE exists,
then print one JSON line: how many notifications arrived, the first and last counter, whether the
counter ever went back (a restarted gateway counts from 0 again), and every status change the
server sent (BadShutdown when the server goes away). Run by tests/real_peers/gateway_demo_serve.rs across two
passes of `demo --serve`. No check here depends on this machine's speed: the Rust test decides.

usage: asyncua_watch.py OPC_URL STOP_FILE
"""

import asyncio
import json
import os
import sys

from asyncua import Client

from asyncua_identification import box_variable


class Watch:
    def __init__(self):
        self.values = []
        self.status = []

    def datachange_notification(self, node, val, data):
        self.values.append(int(val))

    def status_change_notification(self, status):
        self.status.append(str(status))


async def main(url, stop_file):
    out = {"notifications": 0, "status_changes": [], "error": None}
    watch = Watch()
    try:
        async with Client(url, timeout=30) as c:
            node = await box_variable(c, "Monitoring/Compensation/Cycles")
            sub = await c.create_subscription(200, watch)
            await sub.subscribe_data_change([node])
            print(json.dumps({"event": "subscribed"}), flush=True)
            while not os.path.exists(stop_file):
                await asyncio.sleep(0.2)
            # The session is still usable at the end: a read answers.
            out["last_read"] = int(await node.read_value())
    except Exception as e:  # reported, the Rust test fails on it
        out["error"] = f"{type(e).__name__}: {e}"
    v = watch.values
    out.update({
        "notifications": len(v),
        "first": v[0] if v else None,
        "last": v[-1] if v else None,
        "went_back": any(b < a for a, b in zip(v, v[1:])),
        "status_changes": watch.status,
    })
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2]))
