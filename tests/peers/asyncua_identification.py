"""asyncua (pinned in scripts/setup-peers.sh): print the box name and the model hash the gateway's
OPC UA server shows (`Machines/<box>/Identification/ModelSha256`), as one JSON line. Run by
tests/real_peers/gateway_demo_serve.rs and tests/real_peers/gateway_model_switch.rs.

usage: asyncua_identification.py OPC_URL
"""

import asyncio
import json
import sys

from asyncua import Client, ua


async def machine(c):
    """The box's node (the first under Objects/Machines), or None. Also used by asyncua_watch.py."""
    for ch in await c.nodes.objects.get_children():
        if (await ch.read_browse_name()).Name == "Machines":
            return (await ch.get_children())[0]
    return None


async def box_variable(c, path):
    """The variable `Machines/<box>/<path>` (node id in the box's namespace); raises without a box.
    Used by asyncua_watch.py and asyncua_quality.py."""
    box = await machine(c)
    if box is None:
        raise RuntimeError("no Machines folder")
    name = (await box.read_browse_name()).Name
    return c.get_node(ua.NodeId(f"Machines/{name}/{path}", box.nodeid.NamespaceIndex))


async def main(url):
    async with Client(url, timeout=30) as c:
        box = await machine(c)
        if box is None:
            print("FAIL: no Machines folder", flush=True)
            sys.exit(1)
        name = (await box.read_browse_name()).Name
        ns = box.nodeid.NamespaceIndex
        node = c.get_node(ua.NodeId(f"Machines/{name}/Identification/ModelSha256", ns))
        print(json.dumps({"box": name, "sha256": await node.read_value()}), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1]))
