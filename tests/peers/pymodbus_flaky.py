"""pymodbus peer whose device starts answering with exceptions and stops again, for
tests/real_peers/bus_modbus_faults.rs.

Serves Modbus TCP on 127.0.0.1:PORT, unit 1: input registers 0..1 = 215, 223 (0.1 degC: 21.5, 22.3).
Commands on stdin, one per line, each acknowledged on stdout:
  exceptions -> unit 1 has no input registers at 0..1: every read gets exception 02 (`OK exceptions`)
  normal     -> the registers are back                                          (`OK normal`)
Usage: python pymodbus_flaky.py PORT. Prints READY when serving.
"""
import asyncio
import sys

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator.simcore import SimCore

# pymodbus data blocks are 1-based: address 1 here is protocol address 0.
NORMAL = ModbusDeviceContext(ir=ModbusSequentialDataBlock(1, [215, 223]))
# Registers only from protocol address 100 on: reads of 0..1 are an illegal data address.
SHIFTED = ModbusDeviceContext(ir=ModbusSequentialDataBlock(101, [0, 0]))


async def commands(server):
    # pymodbus 3.16 serves from a SimCore built at server start (ModbusServerContext is converted):
    # switching the unit's map means switching its runtime there.
    runtimes = {
        "normal": server.context.devices[1],
        "exceptions": SimCore(ModbusServerContext(devices={1: SHIFTED}, single=False).simdevices).devices[1],
    }
    loop = asyncio.get_running_loop()
    while True:
        raw = await loop.run_in_executor(None, sys.stdin.readline)
        if raw == "":
            return
        cmd = raw.strip()
        if cmd in ("exceptions", "normal"):
            server.context.devices[1] = runtimes[cmd]
            print(f"OK {cmd}", flush=True)
        elif cmd:
            print(f"ERR unknown command {cmd}", flush=True)


async def main():
    ctx = ModbusServerContext(devices={1: NORMAL}, single=False)
    server = ModbusTcpServer(context=ctx, address=("127.0.0.1", int(sys.argv[1])))
    task = asyncio.create_task(server.serve_forever())
    await asyncio.sleep(0.2)
    print("READY", flush=True)
    await commands(server)
    await server.shutdown()
    task.cancel()


asyncio.run(main())
