"""asyncua (pinned in scripts/setup-peers.sh) against the gateway's OPC UA server configured with a
certificate user (`[[opcua.cert_users]]`): run by tests/real_peers/gateway_opcua.rs.

usage: asyncua_certs.py gen WORK_DIR
       asyncua_certs.py check OPC_URL WORK_DIR

`gen` makes two user certificates with their keys (user-good.*, user-other.*) and the client
application's certificate, before the gateway starts (the field config names user-good.der).
`check`: the encrypted endpoint offers a Certificate token; the declared certificate with its key
reads a Correction; the other certificate is refused, and so is the declared certificate signed
with the other key. Prints one JSON line.
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


async def gen(work):
    work = Path(work)
    for stem, cn in [("client", "retrocomp test client app"), ("user-good", "mes operator"),
                     ("user-other", "someone else")]:
        await setup_self_signed_certificate(
            work / f"{stem}-key.pem", work / f"{stem}.der", "urn:retrocomp:test:asyncua",
            "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": cn})


async def cert_client(url, work, user_cert, user_key):
    c = Client(url, timeout=30)
    c.application_uri = "urn:retrocomp:test:asyncua"
    await c.set_security_string(
        f"Basic256Sha256,SignAndEncrypt,{work / 'client.der'},{work / 'client-key.pem'}")
    await c.load_client_certificate(str(work / user_cert))
    await c.load_private_key(str(work / user_key))
    return c


async def refused(url, work, cert, key):
    try:
        c = await cert_client(url, work, cert, key)
        async with c:
            pass
    except Exception as e:  # the session activation fails (BadIdentityTokenRejected/Invalid)
        return f"{type(e).__name__}: {e}"[:200]
    fail(f"{cert} signed with {key} was accepted")


async def check(url, work):
    work = Path(work)
    endpoints = await Client(url, timeout=30).connect_and_get_server_endpoints()
    offered = sorted(
        (e.SecurityPolicyUri.rsplit("#", 1)[-1], e.SecurityMode.name,
         ",".join(sorted(t.TokenType.name for t in e.UserIdentityTokens)))
        for e in endpoints)

    other_cert = await refused(url, work, "user-other.der", "user-other-key.pem")
    wrong_key = await refused(url, work, "user-good.der", "user-other-key.pem")

    c = await cert_client(url, work, "user-good.der", "user-good-key.pem")
    async with c:
        machines = None
        for ch in await c.nodes.objects.get_children():
            if (await ch.read_browse_name()).Name == "Machines":
                machines = ch
        if machines is None:
            fail("no Machines folder for the certificate user")
        box = (await machines.get_children())[0]
        name = (await box.read_browse_name()).Name
        ns = box.nodeid.NamespaceIndex
        node = c.get_node(ua.NodeId(f"Machines/{name}/Monitoring/Axes/X/Correction", ns))
        value = await node.read_value()

    print(json.dumps({
        "endpoints": offered,
        "other_certificate": other_cert,
        "wrong_key": wrong_key,
        "cert_user_read_um": value,
    }), flush=True)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "gen":
        asyncio.run(gen(sys.argv[2]))
    elif len(sys.argv) == 4 and sys.argv[1] == "check":
        asyncio.run(check(sys.argv[2], sys.argv[3]))
    else:
        fail("usage: asyncua_certs.py gen WORK_DIR | check OPC_URL WORK_DIR")
