"""python-can peer on the socketcand interface (for tests/real_peers/bus_can_peers.rs).

Joins HOST:PORT bus can0, prints READY, sends a CiA 406 position TPDO (node 1, 12345 counts), an
extended-id frame with no data and a heartbeat (node 1 operational); then prints every frame it
receives as `RX <id hex> <ext 0|1> <data hex>` until it has seen N frames, then `DONE`.
Usage: python pycan_socketcand.py HOST PORT N
"""
import sys

import can

host, port, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
with can.Bus(interface="socketcand", host=host, port=port, channel="can0") as bus:
    print("READY", flush=True)
    bus.send(can.Message(arbitration_id=0x181, data=(12345).to_bytes(4, "little"), is_extended_id=False))
    bus.send(can.Message(arbitration_id=0x18FF50E5, data=b"", is_extended_id=True))
    bus.send(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))
    seen = 0
    while seen < n:
        msg = bus.recv(timeout=10)
        if msg is None:
            print("TIMEOUT", flush=True)
            sys.exit(1)
        seen += 1
        print(f"RX {msg.arbitration_id:X} {int(msg.is_extended_id)} {msg.data.hex()}", flush=True)
    print("DONE", flush=True)
