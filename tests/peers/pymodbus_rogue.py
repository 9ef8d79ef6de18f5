"""pymodbus client that plays a peer writing the origin-shift server's registers, for
tests/real_peers/listener_allow_writes.rs.

Usage: python pymodbus_rogue.py HOST PORT SOURCE_IP. Connects from SOURCE_IP (127.0.0.2 plays a
rogue host on the network), then prints one line per request:
  FC06 ok | FC06 exception N      (write register 11 = 0x7FFF, a held value far beyond any clamp)
  FC16 ok | FC16 exception N      (write registers 10..12 = [20000, 0, 21930], position and marker)
  FC03 ok W0 W1 ... | FC03 exception N   (read registers 10..12)
and READY first, once connected.
"""
import sys

from pymodbus.client import ModbusTcpClient


def show(name, r):
    if r.isError():
        print(f"{name} exception {getattr(r, 'exception_code', '?')}", flush=True)
    elif hasattr(r, "registers") and name == "FC03":
        print(f"{name} ok " + " ".join(str(w) for w in r.registers), flush=True)
    else:
        print(f"{name} ok", flush=True)


def main():
    host, port, source = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    client = ModbusTcpClient(host, port=port, source_address=(source, 0), timeout=5, retries=0)
    if not client.connect():
        print("CONNECT failed", flush=True)
        sys.exit(1)
    print("READY", flush=True)
    show("FC06", client.write_register(11, 0x7FFF, device_id=1))
    show("FC16", client.write_registers(10, [20000, 0, 21930], device_id=1))
    show("FC03", client.read_holding_registers(10, count=3, device_id=1))
    client.close()


if __name__ == "__main__":
    main()
