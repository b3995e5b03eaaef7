#!/usr/bin/env python3
"""Writes the committed seed corpora fuzz/seeds/<target>/ from proto-core/tests/vectors/*.hex.

Run from anywhere: python3 fuzz/make-seeds.py. The seeds are committed; rerun after adding vectors.

- rtu:   every RTU frame of the vectors (the vectors without CRC get one)
- ascii: the same frames as Modbus ASCII, and a stream of two frames with junk between them
- pdu:   [len(request PDU)] request PDU, response PDU, for each request with its answers
- slave: the fuzz_slave script: address, setup 0xA0 (9600 Bd, multiplier 1, normal mode),
         the request in receive operations of up to 64 bytes, then "follow the deadline"
- 3964:  the 3964(R) telegram bytes of the vectors (kept for the 3964 receiver target)
"""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parent.parent
VECTORS = ROOT / "proto-core" / "tests" / "vectors"
SEEDS = ROOT / "fuzz" / "seeds"


def parse(path):
    data = []
    for line in path.read_text().splitlines():
        if line.lstrip().startswith("#"):
            continue
        data.extend(int(tok, 16) for tok in line.split())
    return bytes(data)


def crc16_modbus(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def rtu(address, pdu):
    body = bytes([address]) + pdu
    crc = crc16_modbus(body)
    return body + bytes([crc & 0xFF, crc >> 8])


def ascii_frame(address, pdu):
    body = bytes([address]) + pdu
    lrc = (-sum(body)) & 0xFF
    return b":" + (body + bytes([lrc])).hex().upper().encode() + b"\r\n"


def slave_script(frame):
    out = bytearray([frame[0], 0xA0])
    for i in range(0, len(frame), 64):
        part = frame[i : i + 64]
        out.append((len(part) - 1) << 2)
        out.extend(part)
    out.append(0x02)
    return bytes(out)


def write(target, name, data):
    folder = SEEDS / target
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_bytes(data)


def main():
    vectors = {p.stem: parse(p) for p in sorted(VECTORS.glob("*.hex"))}
    frames = {}
    for name, data in vectors.items():
        if name.startswith("3964"):
            write("3964", name, data)
        elif "-pdu-" in name:
            # address and PDU as the manual prints them, without CRC
            frames[name] = rtu(data[0], data[1:])
        else:
            frames[name] = data
    for name, frame in frames.items():
        assert crc16_modbus(frame[:-2]) == frame[-2] | frame[-1] << 8, name
        write("rtu", name, frame)
        write("ascii", name, ascii_frame(frame[0], frame[1:-2]))
        if name.endswith("-request"):
            write("slave", name, slave_script(frame))
    # A stream: junk, a frame, a ':' restart, a frame.
    names = sorted(frames)
    a, b = frames[names[0]], frames[names[1]]
    stream = b"xx" + ascii_frame(a[0], a[1:-2]) + b":12" + ascii_frame(b[0], b[1:-2])
    write("ascii", "stream-junk-restart", stream)
    # Request and answer PDUs.
    for name, frame in frames.items():
        m = re.fullmatch(r"(.*)-request", name)
        if not m:
            continue
        request = frame[1:-2]
        for other, answer in frames.items():
            if other == name or not other.startswith(m.group(1) + "-"):
                continue
            if other.endswith(("-response", "-exception")):
                write("pdu", f"{m.group(1)}--{other[len(m.group(1)) + 1:]}",
                      bytes([len(request)]) + request + answer[1:-2])
    # Two requests back to back, a line fault and a pause, for the slave.
    req = [f for n, f in frames.items() if n.endswith("-request") and f[0] == 2]
    write("slave", "two-requests-fault",
          bytes([2, 0xA3]) + bytes([(len(req[0]) - 1) << 2]) + req[0]
          + bytes([(len(req[1]) - 1) << 2]) + req[1] + bytes([0x07, 0x41, 0x02, 0x02]))


if __name__ == "__main__":
    main()
