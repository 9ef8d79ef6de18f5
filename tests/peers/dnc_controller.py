"""A DNC controller's serial input, played by pyserial: a buffer of N lines that it fills from the
line, sending XOFF (DC3) when one line of room is left and XON (DC1) when it has drained to one,
and empties one line every EXEC_MS (executing at feed). Every line received is written to OUT as
received; at the tape end (second `%`) it prints
`DONE received=<lines> overrun=<lines beyond N> max_fill=<lines> xoffs=<count>` and exits.


usage: dnc_controller.py DEVICE BAUD OUT EXEC_MS BUFFER_LINES [TAPE_MARKS]
(TAPE_MARKS: the `%` lines that end the transfer, 2 by default; 1 for a transfer resumed after
the opening `%`.)
"""

import sys
import time

import serial

XON, XOFF = b"\x11", b"\x13"


def main():
    dev, baud, out, exec_ms, n = sys.argv[1], int(sys.argv[2]), sys.argv[3], float(sys.argv[4]), int(sys.argv[5])
    marks = int(sys.argv[6]) if len(sys.argv) > 6 else 2
    port = serial.Serial(dev, baud, timeout=0.005)
    buf, partial = [], b""
    received = overrun = max_fill = xoffs = tape_marks = 0
    held = False
    next_exec = None
    print("READY", flush=True)
    with open(out, "wb") as f:
        while True:
            partial += port.read(256)
            while b"\n" in partial:
                line, partial = partial.split(b"\n", 1)
                line = line.rstrip(b"\r").lstrip(b"\x00")
                f.write(line + b"\n")
                f.flush()
                received += 1
                buf.append(line)
                if len(buf) > n:
                    overrun += 1
                max_fill = max(max_fill, len(buf))
                if line.strip() == b"%":
                    tape_marks += 1
            if not held and len(buf) >= n - 1:
                port.write(XOFF)
                port.flush()
                held, xoffs = True, xoffs + 1
            now = time.monotonic()
            if buf:
                if next_exec is None:
                    next_exec = now + exec_ms / 1000.0
                if now >= next_exec:
                    buf.pop(0)
                    next_exec = now + exec_ms / 1000.0 if buf else None
            if held and len(buf) <= 1:
                port.write(XON)
                port.flush()
                held = False
            if tape_marks >= marks and not buf:
                print(f"DONE received={received} overrun={overrun} max_fill={max_fill} xoffs={xoffs}", flush=True)
                return


if __name__ == "__main__":
    main()
