"""A temperature line on a serial port, played by pyserial: every 50 ms writes
`<x_mm> <T_C>` (the generic line format) with T rising from T0 at RATE K/s, so a DNC transfer
meets a drifting machine.

usage: dnc_sensor.py DEVICE BAUD T0_C RATE_K_PER_S
"""

import sys
import time

import serial


def main():
    dev, baud, t0, rate = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
    port = serial.Serial(dev, baud)
    print("READY", flush=True)
    start = time.monotonic()
    while True:
        t = time.monotonic() - start
        port.write(f"0.000 {t0 + rate * t:.3f}\r\n".encode("ascii"))
        time.sleep(0.05)


if __name__ == "__main__":
    main()
