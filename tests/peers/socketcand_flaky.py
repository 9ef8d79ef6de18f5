"""A socketcand server (rawmode) that hangs up and comes back, for tests/real_peers/bus_can_recovery.rs.

Speaks the socketcand protocol (linux-can/socketcand doc/protocol.md, src/state_raw.c): `< hi >`,
`< open can0 >` -> `< ok >`, `< rawmode >` -> `< ok >`, then `< frame ID SEC.USEC DATA >` every 5 ms
(a CiA 406 TPDO1 of node 1: position counts, little-endian u32) and `< error CLASS SEC.USEC >` for
error frames, as socketcand forwards them. Every message it sends is first parsed by python-can's own
socketcand client parser (can.interfaces.socketcand.convert_ascii_message_to_can_message), so it
only ever sends what the python-can client would accept.

Prints READY, then `PORT <n>`. Commands on stdin, one per line (each acknowledged on stdout):
  counts N   -> send position N counts from now on           (`OK counts N`)
  hangup     -> close the client AND stop listening           (`HUNGUP`)
  listen     -> listen again on the same port                 (`LISTENING`)
  busoff     -> send `< error 040 … >` and stop sending frames (`SENT busoff`)
  restarted  -> send `< error 100 … >` and send frames again   (`SENT restarted`)
Prints `CONNECTED <k>` when the k-th client finished the rawmode handshake and `RX <msg>` for what a
client sends. Usage: python socketcand_flaky.py
"""
import asyncio
import sys
import time

from can.interfaces.socketcand.socketcand import convert_ascii_message_to_can_message

state = {"counts": 100000, "frames_on": True, "writer": None, "server": None, "port": 0, "clients": 0}


def say(line):
    print(line, flush=True)


def stamp():
    t = time.time()
    return f"{int(t)}.{int((t % 1) * 1e6):06d}"


async def send(writer, msg):
    parsed = convert_ascii_message_to_can_message(msg) if msg.startswith(("< frame", "< error")) else True
    assert parsed is not None, f"python-can would not accept {msg!r}"
    writer.write(msg.encode())
    await writer.drain()


async def read_msg(reader):
    buf = b""
    while True:
        c = await reader.read(1)
        if not c:
            return None
        buf += c
        if c == b">":
            text = buf.decode().strip()
            return text[text.index("<"):]


async def client(reader, writer):
    try:
        await send(writer, "< hi >")
        if not (await read_msg(reader) or "").startswith("< open "):
            return writer.close()
        await send(writer, "< ok >")
        if (await read_msg(reader)) != "< rawmode >":
            return writer.close()
        await send(writer, "< ok >")
        state["clients"] += 1
        state["writer"] = writer
        say(f"CONNECTED {state['clients']}")
        while True:
            m = await read_msg(reader)
            if m is None:
                break
            say(f"RX {m}")
    except (ConnectionError, OSError):
        pass
    finally:
        if state["writer"] is writer:
            state["writer"] = None


async def frames():
    while True:
        await asyncio.sleep(0.005)
        w = state["writer"]
        if w is None or not state["frames_on"]:
            continue
        data = (state["counts"] & 0xFFFFFFFF).to_bytes(4, "little").hex().upper()
        try:
            await send(w, f"< frame 181 {stamp()} {data} >")
        except (ConnectionError, OSError):
            state["writer"] = None


async def listen():
    state["server"] = await asyncio.start_server(client, "127.0.0.1", state["port"], reuse_address=True)
    state["port"] = state["server"].sockets[0].getsockname()[1]


async def commands():
    loop = asyncio.get_running_loop()
    while True:
        raw = await loop.run_in_executor(None, sys.stdin.readline)
        if raw == "":
            return  # the test closed our stdin (or died): stop
        line = raw.strip()
        if not line:
            continue
        cmd, *arg = line.split()
        if cmd == "counts":
            state["counts"] = int(arg[0])
            say(f"OK counts {arg[0]}")
        elif cmd == "hangup":
            w, state["writer"] = state["writer"], None
            if w is not None:
                w.close()
            state["server"].close()
            try:
                await asyncio.wait_for(state["server"].wait_closed(), 5)
            except asyncio.TimeoutError:
                pass
            say("HUNGUP")
        elif cmd == "listen":
            await listen()
            say("LISTENING")
        elif cmd in ("busoff", "restarted"):
            state["frames_on"] = cmd == "restarted"
            w = state["writer"]
            if w is not None:
                await send(w, f"< error {'040' if cmd == 'busoff' else '100'} {stamp()} >")
            say(f"SENT {cmd}")
        else:
            say(f"ERR unknown command {line}")


async def main():
    await listen()
    say("READY")
    say(f"PORT {state['port']}")
    asyncio.create_task(frames())
    await commands()


asyncio.run(main())
