"""A stock Sparkplug B host application for tests/real_peers/telemetry_stock_host.rs: mqtt-spb-wrapper's
MqttSpbEntityScada (its host-application class) subscribes to a group, parses every payload with
its SpbPayloadParser and keeps each edge node's data table; this script only prints what the
host's birth/data/death callbacks receive, one JSON line per message.

One adaptation, and why: mqtt-spb-wrapper 2.1.2 keeps its data table by metric name and does not
resolve aliases (an NDATA metric sent by alias only, as Sparkplug 3.0 requires once a birth
defined the alias, raises KeyError in its table update). The entity's data update is wrapped to
put back each metric's name from the alias table of the node's last NBIRTH, nothing else.

usage: spb_stock_host.py PORT GROUP
stdout: READY once connected; then {"type": "NBIRTH"|"NDATA"|"NDEATH", "node", "seq", "metrics":
[{"name", "alias", "datatype", "null", "value", "properties"}], "table": {...}} per message
("table": the host's own data table of that node after an NDATA).
"""

import json
import sys
import threading
import time

from mqtt_spb_wrapper import MqttSpbEntityScada
from mqtt_spb_wrapper.spb_base import SpbEntity

PORT, GROUP = int(sys.argv[1]), sys.argv[2]
out_lock = threading.Lock()
aliases = {}  # node -> {alias: name}, from its last NBIRTH


def emit(obj):
    with out_lock:
        print(obj if isinstance(obj, str) else json.dumps(obj), flush=True)


_data_update = SpbEntity._deserialize_payload_metric


def _with_names(self, value_group, metric_value, skip_callback=False):
    if "name" not in metric_value and "alias" in metric_value:
        table = aliases.get(self.spb_eon_name, {})
        name = table.get(int(metric_value["alias"]))
        if name is None:
            return
        metric_value["name"] = name
    return _data_update(self, value_group, metric_value, skip_callback)


SpbEntity._deserialize_payload_metric = _with_names


def metrics_of(node, payload):
    out = []
    for m in payload.get("metrics", []):
        alias = int(m["alias"]) if "alias" in m else None
        name = m.get("name") or aliases.get(node, {}).get(alias)
        out.append({
            "name": name,
            "alias": alias,
            "datatype": m.get("datatype"),
            "null": m.get("isNull", False),
            "value": m.get("value"),
            "properties": m.get("properties", {}).get("key_value"),
        })
    return out


def on_birth(topic, payload):
    node = topic.eon_name
    aliases[node] = {
        int(m["alias"]): m["name"] for m in payload.get("metrics", []) if "alias" in m
    }
    emit({"type": "NBIRTH", "node": node, "seq": payload.get("seq"),
          "metrics": metrics_of(node, payload)})


def on_data(topic, payload):
    node = topic.eon_name
    entity = host.get_edge_node(node)
    table = {n: entity.data.get_value(n) for n in entity.data.get_names()}
    emit({"type": "NDATA", "node": node, "seq": payload.get("seq"),
          "metrics": metrics_of(node, payload), "table": table})


def on_death(topic, payload):
    emit({"type": "NDEATH", "node": topic.eon_name, "metrics": metrics_of(topic.eon_name, payload)})


def say_online(rc):
    # Sparkplug 3.0 primary host STATE (the wrapper publishes only the 2.2 form): the box waits
    # for it before its NBIRTH, so a host reconnecting after a broker restart sees that NBIRTH.
    # Sent after the wrapper's subscribe on the same connection, so the broker has the
    # subscription by then.
    if rc == 0:
        state = {"online": True, "timestamp": int(time.time() * 1000)}
        host._mqtt.publish("spBv1.0/STATE/stock-judge", json.dumps(state), qos=1, retain=True)
        emit({"event": "online"})


host = MqttSpbEntityScada(spb_group_name=GROUP, spb_scada_name="stock-judge",
                          callback_birth=on_birth, callback_data=on_data,
                          callback_death=on_death)
host.on_connect = say_online
deadline = time.time() + 60
while not host.connect(host="127.0.0.1", port=PORT):
    if time.time() > deadline:
        sys.exit("the stock host could not connect")
    time.sleep(0.2)
emit("READY")
for line in sys.stdin:
    if line.strip() == "QUIT":
        break
host.disconnect(skip_death_publish=True)
