"""pymodbus peer: serves a PT100 module register map over Modbus TCP or RTU (for tests/real_peers/bus_modbus_peers.rs).

Map (0-based protocol addresses; pymodbus data blocks are 1-based, hence the +1 below):
  input registers 0..3   int16, 0.1 degC: 21.5, 22.3, 19.8, -4.5   (Phoenix RAD-PT100-4 style, FC04)
  holding 0..1           float32 ABCD   23.456                     (controlbox TB260 style, FC03)
  holding 10..11         float32 CDAB   -1.25
  holding 20..21         int32   CDAB   -100000
Usage: python pymodbus_pt100.py tcp PORT | rtu DEVICE BAUD
Prints READY when serving.
"""
import asyncio
import struct
import sys

from pymodbus import FramerType
from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.server import StartAsyncSerialServer, StartAsyncTcpServer


def words_f32(v, cdab=False):
    hi, lo = struct.unpack(">HH", struct.pack(">f", v))
    return [lo, hi] if cdab else [hi, lo]


def words_i32(v, cdab=False):
    hi, lo = struct.unpack(">HH", struct.pack(">i", v))
    return [lo, hi] if cdab else [hi, lo]


def context():
    ir = [215, 223, 198, (-45) & 0xFFFF]
    hr = [0] * 22
    hr[0:2] = words_f32(23.456)
    hr[10:12] = words_f32(-1.25, cdab=True)
    hr[20:22] = words_i32(-100000, cdab=True)
    dev = ModbusDeviceContext(
        ir=ModbusSequentialDataBlock(1, ir),
        hr=ModbusSequentialDataBlock(1, hr),
    )
    return ModbusServerContext(devices={1: dev}, single=False)


async def main():
    mode = sys.argv[1]
    ctx = context()
    print("READY", flush=True)
    if mode == "tcp":
        await StartAsyncTcpServer(context=ctx, address=("127.0.0.1", int(sys.argv[2])))
    elif mode == "rtu":
        await StartAsyncSerialServer(
            context=ctx, framer=FramerType.RTU, port=sys.argv[2], baudrate=int(sys.argv[3])
        )
    else:
        sys.exit(f"unknown mode {mode}")


if __name__ == "__main__":
    asyncio.run(main())
