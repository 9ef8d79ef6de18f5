"""asyncua (pinned in scripts/setup-peers.sh) against the gateway's OPC UA server configured with a
user: run by tests/real_peers/gateway_opcua.rs.

usage: asyncua_users.py OPC_URL USER PASSWORD WORK_DIR

Checks: the endpoints offer anonymous only on SecurityPolicy None and user/password on
Basic256Sha256 SignAndEncrypt; a wrong password is refused; the right one over the encrypted
channel reads a Correction; a write is refused for that user too. Prints one JSON line.
"""

import asyncio
import json
import sys
from pathlib import Path

from asyncua import Client, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from cryptography.x509.oid import ExtendedKeyUsageOID


def fail(msg):
    print(f"FAIL: {msg}", flush=True)
    sys.exit(1)


async def secure_client(url, user, password, key, cert):
    c = Client(url, timeout=30)
    c.application_uri = "urn:retrocomp:test:asyncua"
    c.set_user(user)
    c.set_password(password)
    await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
    return c


async def main(url, user, password, work):
    work = Path(work)
    key, cert = work / "client-key.pem", work / "client-cert.der"
    await setup_self_signed_certificate(
        key, cert, "urn:retrocomp:test:asyncua", "localhost",
        [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "retrocomp test client"})

    endpoints = await Client(url, timeout=30).connect_and_get_server_endpoints()
    offered = sorted(
        (e.SecurityPolicyUri.rsplit("#", 1)[-1], e.SecurityMode.name,
         ",".join(sorted(t.TokenType.name for t in e.UserIdentityTokens)))
        for e in endpoints)

    wrong = None
    try:
        c = await secure_client(url, user, password + "-wrong", key, cert)
        async with c:
            pass
    except Exception as e:  # the server closes the session activation with BadUserAccessDenied
        wrong = f"{type(e).__name__}: {e}"
    if wrong is None:
        fail("a wrong password was accepted")

    c = await secure_client(url, user, password, key, cert)
    async with c:
        machines = None
        for ch in await c.nodes.objects.get_children():
            if (await ch.read_browse_name()).Name == "Machines":
                machines = ch
        if machines is None:
            fail("no Machines folder for the user")
        box = (await machines.get_children())[0]
        name = (await box.read_browse_name()).Name
        ns = box.nodeid.NamespaceIndex
        node = c.get_node(ua.NodeId(f"Machines/{name}/Monitoring/Axes/X/Correction", ns))
        value = await node.read_value()
        refused = None
        try:
            await node.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))
        except ua.UaStatusCodeError as e:
            refused = type(e).__name__
        if refused is None:
            fail("the user's write was accepted")

    print(json.dumps({
        "endpoints": offered,
        "wrong_password": wrong[:200],
        "user_read_um": value,
        "user_write_refused": refused,
    }), flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 5:
        fail("usage: asyncua_users.py OPC_URL USER PASSWORD WORK_DIR")
    asyncio.run(main(*sys.argv[1:]))
