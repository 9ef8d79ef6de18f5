"""asyncua (pinned in scripts/setup-peers.sh): what a plant client learns about a value's quality
from the gateway's OPC UA server. Run by tests/real_peers/gateway_opcua.rs while hil-sim silences the
temperature node for a while.

usage: asyncua_quality.py OPC_URL CHANNEL

One session, one subscription to `Monitoring/Sensors/<CHANNEL>/Value`, held until the value has
been Good, then Uncertain (the channel went stale), then Good again, or 60 s have passed. Every
notification is recorded with its StatusCode name, SourceTimestamp and ServerTimestamp (Unix s)
and the client's wall time when it arrived. Also reads `Server/ServerStatus/BuildInfo`, and holds
a second subscription to `AlarmConditionType` events on the `Server` object: every alarm event is
recorded (EventType, SourceNode, SourceName, Message, Severity, ConditionName, Retain,
ActiveState/Id, Time) until the channel's `stale` alarm has been raised and cleared (or the same
60 s have passed). Prints one JSON line; the Rust test judges it (nothing here depends on this
machine's speed).
"""

import asyncio
import json
import sys
import time

from asyncua import Client, ua

from asyncua_identification import box_variable, machine

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


class Alarms:
    """Every AlarmConditionType event the server sends, as JSON."""

    def __init__(self):
        self.seen = []

    def event_notification(self, event):
        f = event.get_event_props_as_fields_dict()

        def v(name):
            var = f.get(name)
            return None if var is None else var.Value

        msg, time_ = v("Message"), v("Time")
        self.seen.append({
            "event_type": v("EventType").to_string() if v("EventType") is not None else None,
            "source_node": v("SourceNode").to_string() if v("SourceNode") is not None else None,
            "source_name": v("SourceName"),
            "message": msg.Text if msg is not None else None,
            "severity": v("Severity"),
            "condition_name": v("ConditionName"),
            "retain": v("Retain"),
            "active": v("ActiveState/Id"),
            "time_s": unix(time_),
            "event_id": v("EventId").hex() if v("EventId") is not None else None,
        })

    def cleared(self, condition):
        """Raised and then cleared: an active event for `condition`, a later inactive one."""
        raised = False
        for e in self.seen:
            if e["condition_name"] == condition:
                if e["active"]:
                    raised = True
                elif raised:
                    return True
        return False


# The fields read, each by the type that declares it (browse path below that type).
FIELDS = [
    (ua.ObjectIds.BaseEventType, ["EventId"]),
    (ua.ObjectIds.BaseEventType, ["EventType"]),
    (ua.ObjectIds.BaseEventType, ["SourceNode"]),
    (ua.ObjectIds.BaseEventType, ["SourceName"]),
    (ua.ObjectIds.BaseEventType, ["Time"]),
    (ua.ObjectIds.BaseEventType, ["Message"]),
    (ua.ObjectIds.BaseEventType, ["Severity"]),
    (ua.ObjectIds.ConditionType, ["ConditionName"]),
    (ua.ObjectIds.ConditionType, ["Retain"]),
    (ua.ObjectIds.AlarmConditionType, ["ActiveState", "Id"]),
]


def alarm_filter():
    """An EventFilter for AlarmConditionType and its subtypes with the FIELDS. Not asyncua's
    default filter from the type: async-opcua 0.19 drops the select clauses it cannot resolve
    (e.g. ConditionId, the condition's NodeId) instead of returning a null field for each, so
    asyncua's field list no longer lines up; and its InList compares only numbers, so the
    default where clause (EventType InList [the type and its subtypes]) passes nothing. OfType
    is the standard's own operator for "this type or a subtype"."""
    f = ua.EventFilter()
    for type_id, path in FIELDS:
        op = ua.SimpleAttributeOperand()
        op.TypeDefinitionId = ua.NodeId(type_id)
        op.BrowsePath = [ua.QualifiedName(p, 0) for p in path]
        op.AttributeId = ua.AttributeIds.Value
        f.SelectClauses.append(op)
    of_type = ua.LiteralOperand(Value=ua.Variant(ua.NodeId(ua.ObjectIds.AlarmConditionType)))
    f.WhereClause = ua.ContentFilter(Elements=[ua.ContentFilterElement(
        FilterOperator=ua.FilterOperator.OfType, FilterOperands=[of_type])])
    return f


async def main(url, channel):
    out = {"error": None}
    q = Quality()
    alarms = Alarms()
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
            box = await machine(c)
            out["machine_node"] = box.nodeid.to_string()
            notifiers = await c.nodes.server.get_referenced_nodes(
                refs=ua.ObjectIds.HasNotifier, direction=ua.BrowseDirection.Forward)
            out["server_notifiers"] = [n.nodeid.to_string() for n in notifiers]
            out["machine_event_notifier"] = sorted(e.name for e in await box.read_event_notifier())
            alarm_type = c.get_node(ua.ObjectIds.AlarmConditionType)
            events = await c.create_subscription(100, alarms)
            # A queue for a burst (a node going silent stales all its channels at once): asyncua's
            # default 0 gets async-opcua's 1, which keeps only the last event of each publish.
            await events.subscribe_events(c.nodes.server, alarm_type, evfilter=alarm_filter(),
                                          queuesize=1000)
            stale = f"{channel}/stale"
            t0 = time.monotonic()
            while time.monotonic() - t0 < DEADLINE_S:
                if q.recovered() and alarms.cleared(stale):
                    break
                await asyncio.sleep(0.1)
            await sub.delete()
            await events.delete()
    except Exception as e:  # reported, the Rust test fails on it
        out["error"] = f"{type(e).__name__}: {e}"
    out.update({"phases": q.phases(), "recovered": q.recovered(), "notifications": q.seen,
                "alarms": alarms.seen})
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2]))
