"""Third-party OPC UA client (asyncua, pinned in scripts/setup-peers.sh) against the gateway's OPC UA
server, run by tests/real_peers/gateway_opcua.rs while hil-sim drives the machine.

usage: asyncua_client.py OPC_URL STATUS_URL

Anonymous session: browses Objects/Machines/<box>, reads each axis' Correction and checks it
against /status, reads EngineeringUnits, subscribes to the cycle counter and to X's Correction,
tries a write (must be refused). Prints one JSON summary line; exits 1 with a reason on failure.
No check depends on this machine's speed: every wait polls against a generous deadline.
"""

import asyncio
import json
import sys
import time
import urllib.request

from asyncua import Client, ua

DEADLINE_S = 60.0
# A correction this large (µm) means the axes are moving: the demo's corrections reach several µm.
MOVING_UM = 0.1
UNECE_URI = "http://www.opcfoundation.org/UA/units/un/cefact"


def fail(msg):
    print(f"FAIL: {msg}", flush=True)
    sys.exit(1)


def get_status(url):
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.load(r)


async def child(node, name):
    for c in await node.get_children():
        bn = await c.read_browse_name()
        if bn.Name == name:
            return c
    return None


async def walk(node, path, out):
    """Every variable below `node`, by its browse path."""
    for c in await node.get_children():
        bn = (await c.read_browse_name()).Name
        cls = await c.read_node_class()
        p = f"{path}/{bn}" if path else bn
        if cls == ua.NodeClass.Variable:
            out[p] = c
        if cls == ua.NodeClass.Object or bn != "EngineeringUnits":
            await walk(c, p, out)


MACHINERY_URI = "http://opcfoundation.org/UA/Machinery/"
MACHINE_TOOL_URI = "http://opcfoundation.org/UA/MachineTool/"
DI_URI = "http://opcfoundation.org/UA/DI/"


async def is_subtype(client, type_id, base_id):
    """`type_id` is `base_id` or below it (inverse HasSubtype up the type tree)."""
    node = client.get_node(type_id)
    for _ in range(16):
        if node.nodeid == base_id:
            return True
        parents = await node.get_references(ua.ObjectIds.HasSubtype, ua.BrowseDirection.Inverse)
        if not parents:
            return False
        node = client.get_node(parents[0].NodeId)
    return False


async def companion_checks(client, machines, box):
    """OPC 40001-1 / 40501-1: Machines is Machinery's folder; the machines in it found by type
    (HasTypeDefinition a MachineToolType or a subtype); the box's Identification holds DI's
    mandatory properties."""
    machinery = await client.get_namespace_index(MACHINERY_URI)
    machine_tool = await client.get_namespace_index(MACHINE_TOOL_URI)
    di = await client.get_namespace_index(DI_URI)
    if machines.nodeid != ua.NodeId(1001, machinery):
        fail(f"Machines is {machines.nodeid}, not Machinery's i=1001 in ns {machinery}")
    mt_type = ua.NodeId(13, machine_tool)
    type_name = (await client.get_node(mt_type).read_browse_name())
    if (type_name.Name, type_name.NamespaceIndex) != ("MachineToolType", machine_tool):
        fail(f"ns={machine_tool};i=13 is {type_name}")
    found = []
    for m in await machines.get_children(refs=ua.ObjectIds.Organizes):
        t = await m.read_type_definition()
        if t is not None and await is_subtype(client, t, mt_type):
            found.append(m.nodeid)
    if found != [box.nodeid]:
        fail(f"machine tools found by type: {found}, expected [{box.nodeid}]")
    ident = await box.get_child(f"{di}:Identification")
    ident_type = await ident.read_type_definition()
    nameplate = {}
    for name in ("Manufacturer", "SerialNumber", "ProductInstanceUri"):
        v = await (await ident.get_child(f"{di}:{name}")).read_value()
        nameplate[name] = v.Text if isinstance(v, ua.LocalizedText) else v
    components = {}
    for name in ("Monitoring", "Notification", "Production"):
        c = await box.get_child(f"{machine_tool}:{name}")
        components[name] = (await c.read_type_definition()).Identifier
    return {
        "machines": machines.nodeid.to_string(),
        "type_definition": (await box.read_type_definition()).to_string(),
        "machine_tool_ns": machine_tool,
        "identification_type": ident_type.Identifier,
        "nameplate": nameplate,
        "components": components,
    }


class Changes:
    def __init__(self):
        self.values = {}

    def datachange_notification(self, node, val, data):
        self.values.setdefault(node.nodeid.to_string(), []).append(val)


async def main(opc_url, status_url):
    client = Client(opc_url, timeout=30)
    async with client:
        objects = client.nodes.objects
        machines = await child(objects, "Machines")
        if machines is None:
            fail("no Machines folder under Objects")
        boxes = await machines.get_children()
        if len(boxes) != 1:
            fail(f"expected one machine under Machines, got {len(boxes)}")
        box = boxes[0]
        box_name = (await box.read_browse_name()).Name
        companion = await companion_checks(client, machines, box)
        variables = {}
        await walk(box, "", variables)
        ident = {k: await variables[f"Identification/{k}"].read_value()
                 for k in ("Name", "ModelName", "ModelSha256")}
        corr = {p.split("/")[2]: n for p, n in variables.items()
                if p.startswith("Monitoring/Axes/") and p.endswith("/Correction")}
        if not corr:
            fail(f"no Monitoring/Axes/*/Correction in {sorted(variables)}")
        axes = sorted(corr)
        cycles_node = variables["Monitoring/Compensation/Cycles"]

        # Correction vs /status: read the box's cycle counter and every Correction in one Read (the
        # server updates them together), then /status, then read again until the box shows that
        # cycle or a later one: /status's value lies between the two reads' values unless the
        # correction turned within that window (retried).
        nodes = [cycles_node] + [corr[a] for a in axes]
        async def read_all():
            vals = await client.read_values(nodes)
            return vals[0], dict(zip(axes, vals[1:]))
        # Compared until three reads matched AND one of them caught the machine moving (a
        # correction of MOVING_UM or more): on a loaded host the first matches can come before
        # the axes have left home, where every correction is a few hundredths of a µm.
        matched, attempts, nonzero, misses = 0, 0, 0.0, []
        t0 = time.monotonic()
        while matched < 3 or nonzero < MOVING_UM:
            if time.monotonic() - t0 > DEADLINE_S or attempts >= 400:
                fail(f"Correction never bracketed /status while moving ({matched} of {attempts}, "
                     f"largest matched |correction| {nonzero} µm): {misses[-5:]}")
            if matched >= 3:
                await asyncio.sleep(0.1)
            attempts += 1
            c1, v1 = await read_all()
            st = get_status(status_url)
            c2 = st["cycles"]
            s2 = {a["axis"].upper(): a["applied_um"] for a in st["axes"]}
            if sorted(s2) != axes:
                fail(f"/status axes {sorted(s2)} vs OPC UA axes {axes}")
            while True:
                c3, v3 = await read_all()
                if c3 >= c2:
                    break
                if time.monotonic() - t0 > DEADLINE_S:
                    fail(f"the OPC UA cycle counter stays at {c3} < /status's {c2}")
                await asyncio.sleep(0.02)
            if not c1 <= c2 <= c3:
                fail(f"cycle counters out of order: {c1} {c2} {c3}")
            ok = all(min(v1[a], v3[a]) - 1e-9 <= s2[a] <= max(v1[a], v3[a]) + 1e-9 for a in axes)
            if ok:
                matched += 1
                nonzero = max(nonzero, max(abs(s2[a]) for a in axes))
            else:
                misses.append({"v1": v1, "status": s2, "v3": v3})

        # Engineering units: µm ("4H") on corrections; a temperature channel in °C ("CEL").
        units = {}
        for path in [f"Monitoring/Axes/{axes[0]}/Correction"] + [
                p for p in variables if p.startswith("Monitoring/Sensors/T_") and p.endswith("/Value")]:
            eu_node = await child(variables[path], "EngineeringUnits")
            if eu_node is None:
                fail(f"{path} has no EngineeringUnits property")
            eu = await eu_node.read_value()
            if eu.NamespaceUri != UNECE_URI:
                fail(f"{path}: EngineeringUnits namespace {eu.NamespaceUri}")
            units[path] = {"unit_id": eu.UnitId, "symbol": eu.DisplayName.Text}

        # Subscription: the cycle counter changes with every update; X's correction while it moves.
        handler = Changes()
        sub = await client.create_subscription(100, handler)
        watched = [cycles_node, corr[axes[0]]]
        await sub.subscribe_data_change(watched)
        t0 = time.monotonic()
        key = cycles_node.nodeid.to_string()
        while len(handler.values.get(key, [])) < 4 and time.monotonic() - t0 < DEADLINE_S:
            await asyncio.sleep(0.1)
        await sub.delete()
        counts = {k: len(v) for k, v in handler.values.items()}
        cyc = handler.values.get(key, [])
        # The first notification is the initial value; then at least 3 changes.
        if len(cyc) < 4:
            fail(f"subscription: {counts} notifications within {DEADLINE_S} s")
        if any(b <= a for a, b in zip(cyc, cyc[1:])):
            fail(f"cycle counter notifications not increasing: {cyc}")

        # Writes are refused (anonymous, and the whole space is read-only).
        refused = None
        try:
            await corr[axes[0]].write_value(ua.DataValue(ua.Variant(123.0, ua.VariantType.Double)))
        except ua.UaStatusCodeError as e:
            refused = type(e).__name__
        if refused is None:
            fail("an anonymous write to a Correction was accepted")

    print(json.dumps({
        "box": box_name,
        "companion": companion,
        "identification": ident,
        "axes": axes,
        "variables": len(variables),
        "matched": matched,
        "attempts": attempts,
        "max_abs_correction_um": nonzero,
        "units": units,
        "cycle_changes": len(cyc) - 1,
        "notifications": counts,
        "write_refused": refused,
    }), flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        fail("usage: asyncua_client.py OPC_URL STATUS_URL")
    asyncio.run(main(sys.argv[1], sys.argv[2]))
