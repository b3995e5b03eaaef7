"""A Modbus/TCP Security client for the gateway's tests: pymodbus over TLS with a client
certificate.

usage: client.py PORT CA CERT KEY UNIT OP...
OP: r:ADDRESS:COUNT (FC 03), i:ADDRESS:COUNT (FC 04), w:ADDRESS:VALUE (FC 06), or cert:-:-
(the SHA-256 of the server's certificate).
Prints one line per OP: "ok V1,V2,..." / "ok", "exception CODE", "cert HEX", or "error TEXT";
the first line is "connected" or "not connected".
"""

import hashlib
import ssl
import sys

from pymodbus.client import ModbusTlsClient


def main() -> int:
    port, ca, cert, key, unit, *ops = sys.argv[1:]
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    # pymodbus's synchronous client wraps the socket without a server name: the chain is still
    # verified against the CA (CERT_REQUIRED), the name is not.
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_REQUIRED
    ctx.load_verify_locations(ca)
    ctx.load_cert_chain(cert, key)
    client = ModbusTlsClient("127.0.0.1", sslctx=ctx, port=int(port), timeout=5, retries=0)
    try:
        connected = client.connect()
    except (OSError, ssl.SSLError):
        connected = False
    if not connected:
        print("not connected", flush=True)
        return 0
    print("connected", flush=True)
    for op in ops:
        kind, address, arg = op.split(":")
        if kind == "cert":
            der = client.socket.getpeercert(binary_form=True)
            print("cert " + hashlib.sha256(der).hexdigest(), flush=True)
            continue
        try:
            if kind == "r":
                rr = client.read_holding_registers(int(address), count=int(arg), device_id=int(unit))
            elif kind == "i":
                rr = client.read_input_registers(int(address), count=int(arg), device_id=int(unit))
            else:
                rr = client.write_register(int(address), int(arg), device_id=int(unit))
        except Exception as e:  # the connection closed, a timeout
            print(f"error {type(e).__name__}", flush=True)
            continue
        if rr.isError():
            print(f"exception {getattr(rr, 'exception_code', '?')}", flush=True)
        elif kind in ("r", "i"):
            print("ok " + ",".join(str(v) for v in rr.registers), flush=True)
        else:
            print("ok", flush=True)
    client.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
