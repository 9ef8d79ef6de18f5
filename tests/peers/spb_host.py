"""A third-party Sparkplug B host for tests/real_peers/telemetry_mqtt.rs: paho-mqtt subscribes to a group,
mqtt-spb-wrapper's compiled Eclipse sparkplug_b.proto decodes every payload (and its
SpbPayloadParser must accept it), and each message is printed as one JSON line. It also plays the
Sparkplug 3.0 primary host: STATE online (retained, QoS 1) after each (re)subscription, with the
offline STATE as its will, so an edge node waits for it before NBIRTH.

usage: spb_host.py PORT GROUP HOST_ID
stdin: `REBIRTH <edge node>` sends NCMD Node Control/Rebirth = true; `QUIT` exits.
stdout: READY once subscribed and online; then {"event": "online"} after every reconnect and
{"topic", "type", "node", "seq", "timestamp", "metrics": [...]} per message.
"""

import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
from mqtt_spb_wrapper import SpbPayloadParser
from mqtt_spb_wrapper.spb_protobuf.sparkplug_b_pb2 import Payload

PORT, GROUP, HOST_ID = int(sys.argv[1]), sys.argv[2], sys.argv[3]
STATE = f"spBv1.0/STATE/{HOST_ID}"
out_lock = threading.Lock()
ready = threading.Event()


def emit(obj):
    with out_lock:
        print(obj if isinstance(obj, str) else json.dumps(obj), flush=True)


def state(online):
    return json.dumps({"online": online, "timestamp": int(time.time() * 1000)})


def on_connect(client, userdata, flags, rc):
    client.subscribe(f"spBv1.0/{GROUP}/#", qos=1)


def on_subscribe(client, userdata, mid, granted_qos):
    client.publish(STATE, state(True), qos=1, retain=True)
    if ready.is_set():
        emit({"event": "online"})
    else:
        ready.set()
        emit("READY")


def value_of(m):
    kind = m.WhichOneof("value")
    return None if kind is None else getattr(m, kind)


def on_message(client, userdata, msg):
    parts = msg.topic.split("/")
    p = Payload()
    p.ParseFromString(msg.payload)
    parsed = SpbPayloadParser(msg.payload).payload
    metrics = []
    for m in p.metrics:
        metrics.append({
            "name": m.name if m.HasField("name") else None,
            "alias": m.alias if m.HasField("alias") else None,
            "datatype": m.datatype,
            "historical": m.is_historical,
            "value": value_of(m),
        })
    emit({
        "topic": msg.topic,
        "type": parts[2] if len(parts) > 3 else parts[1],
        "node": parts[3] if len(parts) > 3 else None,
        "seq": p.seq if p.HasField("seq") else None,
        "timestamp": p.timestamp if p.HasField("timestamp") else None,
        "wrapper_parsed": parsed is not None,
        "metrics": metrics,
    })


client = mqtt.Client(client_id=f"spb-host-{HOST_ID}", clean_session=True)
client.will_set(STATE, state(False), qos=1, retain=True)
client.reconnect_delay_set(min_delay=1, max_delay=1)
client.on_connect = on_connect
client.on_subscribe = on_subscribe
client.on_message = on_message
client.connect("127.0.0.1", PORT, keepalive=5)
client.loop_start()

for line in sys.stdin:
    words = line.split()
    if not words:
        continue
    if words[0] == "QUIT":
        break
    if words[0] == "REBIRTH":
        cmd = Payload()
        cmd.timestamp = int(time.time() * 1000)
        m = cmd.metrics.add()
        m.name = "Node Control/Rebirth"
        m.datatype = 11  # Boolean
        m.boolean_value = True
        client.publish(f"spBv1.0/{GROUP}/NCMD/{words[1]}", cmd.SerializeToString(), qos=0)
client.loop_stop()
