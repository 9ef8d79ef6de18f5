"""A shop's DNC sender, played by pyserial with XON/XOFF flow control (the kernel stops its output
on the box's DC3): writes PROGRAM line by line with CR LF, then prints `SENT <lines>` (or
`TIMEOUT <line>` if a write was held longer than 60 s) and keeps the port open until killed.

usage: dnc_sender.py DEVICE BAUD PROGRAM
"""

import sys
import time

import serial


def main():
    dev, baud, program = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    port = serial.Serial(dev, baud, xonxoff=True, write_timeout=60)
    print("READY", flush=True)
    lines = open(program, encoding="ascii").read().splitlines()
    for i, line in enumerate(lines, 1):
        try:
            port.write(line.encode("ascii") + b"\r\n")
        except serial.SerialTimeoutException:
            print(f"TIMEOUT {i}", flush=True)
            return
    port.flush()
    print(f"SENT {len(lines)}", flush=True)
    while True:
        time.sleep(1)


if __name__ == "__main__":
    main()
