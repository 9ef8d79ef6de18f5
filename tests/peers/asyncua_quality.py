"""asyncua (pinned in scripts/setup-peers.sh): what a plant client learns about a value's quality
from the gateway's OPC UA server. Run by tests/gateway_opcua.rs while hil-sim silences the
temperature node for a while.

usage: asyncua_quality.py OPC_URL CHANNEL

One session, one subscription to `Monitoring/Sensors/<CHANNEL>/Value`, held until the value has
been Good, then Uncertain (the channel went stale), then Good again, or 60 s have passed. Every
notification is recorded with its StatusCode name, SourceTimestamp and ServerTimestamp (Unix s)
and the client's wall time when it arrived. Also reads `Server/ServerStatus/BuildInfo`. Prints one
JSON line; the Rust test judges it (nothing here depends on this machine's speed).
"""

import asyncio
import json
import sys
import time

from asyncua import Client, ua

from asyncua_identification import box_variable

DEADLINE_S = 60.0


def unix(t):
    return t.timestamp() if t is not None else None


class Quality:
    def __init__(self):
        self.seen = []

    def datachange_notification(self, node, val, data):
        dv = data.monitored_item.Value
        self.seen.append({
            "status": dv.StatusCode.name,
            "value": val,
            "source_s": unix(dv.SourceTimestamp),
            "server_s": unix(dv.ServerTimestamp),
            "arrived_s": time.time(),
        })

    def phases(self):
        """The status sequence with repeats folded: ["Good", "UncertainLastUsableValue", ...]."""
        out = []
        for n in self.seen:
            if not out or out[-1] != n["status"]:
                out.append(n["status"])
        return out

    def recovered(self):
        p = self.phases()
        for i, s in enumerate(p):
            if s.startswith("Uncertain") and "Good" in p[:i] and "Good" in p[i + 1:]:
                return True
        return False


async def main(url, channel):
    out = {"error": None}
    q = Quality()
    try:
        async with Client(url, timeout=30) as c:
            node = await box_variable(c, f"Monitoring/Sensors/{channel}/Value")
            bi = await c.get_node(ua.ObjectIds.Server_ServerStatus_BuildInfo).read_value()
            out["build_info"] = {
                "product_name": bi.ProductName,
                "product_uri": bi.ProductUri,
                "manufacturer": bi.ManufacturerName,
                "software_version": bi.SoftwareVersion,
                "build_date_s": unix(bi.BuildDate),
            }
            sub = await c.create_subscription(100, q)
            # Trigger StatusValue spelled out: it is the standard's default, but async-opcua 0.19
            # compares only the value of an item created without a filter.
            status_value = ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.StatusValue)
            await sub._subscribe(node, ua.AttributeIds.Value, mfilter=status_value)
            t0 = time.monotonic()
            while not q.recovered() and time.monotonic() - t0 < DEADLINE_S:
                await asyncio.sleep(0.1)
            await sub.delete()
    except Exception as e:  # reported, the Rust test fails on it
        out["error"] = f"{type(e).__name__}: {e}"
    out.update({"phases": q.phases(), "recovered": q.recovered(), "notifications": q.seen})
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2]))
