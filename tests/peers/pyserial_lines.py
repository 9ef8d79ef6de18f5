"""pyserial peer: writes instrument lines into a serial device (a pty in tests/real_peers/bus_serial_peers.rs).

Usage: python pyserial_lines.py DEVICE BAUD KIND
KIND dro:      Heidenhain-style STX+sign+9 digits lines for X, Y, Z, twice, with a garbage line and a
               partial line (no terminator) between the blocks.
KIND weighing: weighing-indicator lines: unstable, stable gross, stable net, overload, and noise.
Prints READY after opening the port, DONE after writing.
"""
import sys
import time

import serial

dev, baud, kind = sys.argv[1], int(sys.argv[2]), sys.argv[3]
with serial.Serial(dev, baudrate=baud, timeout=1) as port:
    print("READY", flush=True)
    time.sleep(0.3)  # let the reader open the other end
    if kind == "dro":
        block = [b"\x02+001234500\r\n", b"\x02-000000100\r\n", b"\x02+000010000\r\n"]
        for line in block:
            port.write(line)
        port.write(b"\xff\xfe garbage \r\n\x02+00")  # noise, then a line cut short
        port.write(b"\r\n")
        port.write(b"\x02+000000001\r\n\x02+000000002\r\n\x02+000000003\r\n")
    elif kind == "weighing":
        for line in [b"US,GS,+0001.000kg\r\n", b"ST,GS,+0010.250kg\r\n", b"ST,NT,+0002.000kg\r\n",
                     b"OL,GS,         kg\r\n", b"#####\r\n", b"ST,GS,+0010.500kg\r\n"]:
            port.write(line)
    else:
        sys.exit(f"unknown kind {kind}")
    port.flush()
    print("DONE", flush=True)
    time.sleep(1.0)  # keep the pty open until the reader has drained it
