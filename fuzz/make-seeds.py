#!/usr/bin/env python3
"""Writes the committed seed corpora fuzz/seeds/<target>/ from proto-core/tests/vectors/*.hex.

Run from anywhere: python3 fuzz/make-seeds.py. The seeds are committed; rerun after adding vectors.

- rtu:   every RTU frame of the vectors (the vectors without CRC get one)
- ascii: the same frames as Modbus ASCII, and a stream of two frames with junk between them
- pdu:   [len(request PDU)] request PDU, response PDU, for each request with its answers
- slave: the fuzz_slave script: address, setup 0xA0 (9600 Bd, multiplier 1, normal mode),
         the request in receive operations of up to 64 bytes, then "follow the deadline"
- proc3964: the fuzz_3964 input: a setup byte, then the script; the 3964(R) vectors as a
         telegram received from the partner (STX, our DLE, the bytes, our DLE) and as one we send,
         and raw after the setup byte (the deframer sees them as they are)
- mbap:  every request PDU in an MBAP frame (transaction id = its number, unit id = the slave
         address), all of them pipelined in one stream, and a frame with protocol id 1
- telegram: the fuzz_telegram input: setup, fixed length, then the script; telegrams ended by
         the character delay time, ETX, CR LF and a fixed length, received and sent
- rtu_tap: the fuzz_rtu_tap input: setup 0x21 (9600 Bd, answer timeout 1 s), then each request of the vectors and
         its answers as another master's exchange with silences between the frames, and a
         request left without an answer
- tap3964: the fuzz_tap_3964 input: a setup byte, then both partners' exchanges of the 3964(R)
         vectors (STX, DLE, the telegram, DLE), one refused with NAK and repeated, and an
         initialization conflict
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


def mbap(transaction, unit, pdu):
    return transaction.to_bytes(2, "big") + b"\x00\x00" + (len(pdu) + 1).to_bytes(2, "big") \
        + bytes([unit]) + pdu


def slave_script(frame):
    out = bytearray([frame[0], 0xA0])
    for i in range(0, len(frame), 64):
        part = frame[i : i + 64]
        out.append((len(part) - 1) << 2)
        out.extend(part)
    out.append(0x02)
    return bytes(out)


# Script operations of proto_core::fuzzing (telegram.rs): op & 7, argument op >> 3.
RX, WAIT, TIMEOUT, SEND, TAKE, CONTROL, CONFIRM = 0, 1, 2, 4, 5, 6, 7
STX_OP, DLE_OP = CONTROL | 0 << 3, CONTROL | 1 << 3


def chunks(op, data):
    out = bytearray()
    for i in range(0, len(data), 32):
        part = data[i : i + 32]
        out += bytes([op | (len(part) - 1) << 3]) + part
    return bytes(out)


def write_3964(name, wire):
    # setup: bit 0 set = 3964 without BCC
    setup = 0 if name.startswith("3964r") else 1
    write("proc3964", name + "-raw", bytes([setup]) + wire)
    # The partner sends: STX, we answer DLE (confirmed), the telegram, we answer DLE or NAK.
    write("proc3964", name + "-received",
          bytes([setup, STX_OP, CONFIRM]) + chunks(RX, wire) + bytes([CONFIRM, TIMEOUT]))
    if "bad" not in name:
        # We send the user data: STX out, the partner's DLE, the telegram out, its DLE.
        user = wire[:-3] if setup == 0 else wire[:-2]
        user = user.replace(b"\x10\x10", b"\x10")
        write("proc3964", name + "-sent",
              bytes([setup]) + chunks(SEND, user)
              + bytes([CONFIRM, DLE_OP, CONFIRM, DLE_OP, TIMEOUT]))


def write_telegrams():
    cases = {
        # setup byte (end criterion in bits 0..1), fixed length - 1, received bytes
        "zvz-received": (0, 0, b"HELLO"),
        "fixed-received": (1, 3, b"ABCD"),
        "etx-received": (2, 0, b"ABC\x03"),
        "crlf-received": (3, 0, b"12.5\r\n"),
        "xon-xoff-etx-received": (2 | 1 << 2, 0, b"AB\x13C\x11\x03"),
        "seven-bit-crlf-received": (3 | 1 << 4, 0, b"\xc1B\r\n"),
    }
    for name, (setup, length, data) in cases.items():
        write("telegram", name,
              bytes([setup, length]) + chunks(RX, data) + bytes([TIMEOUT, TAKE]))
    for name, setup in {"etx-sent": 2, "xon-xoff-sent": 2 | 1 << 2, "rts-cts-sent": 2 | 2 << 2,
                        "auto-v24-sent": 2 | 3 << 2}.items():
        # CTS and DSR on (a send does not start while DSR is off under automatic V24 handling,
        # 000 7.2 08 18h), send, confirm, deadlines
        signals = CONFIRM | (1 | 2 | 4) << 3
        write("telegram", name,
              bytes([setup, 0, signals]) + chunks(SEND, b"ABC\x03")
              + bytes([TIMEOUT, CONFIRM, TIMEOUT, CONFIRM, TIMEOUT]))


# Script operations of proto_core::fuzzing (tap.rs). RTU tap: op & 3, argument op >> 2.
TAP_RX, TAP_SILENCE, TAP_TIMEOUT = 0, 1, 2
# 3964(R) tap: op & 7, argument op >> 3.
A_RX, B_RX, Y_TIMEOUT, A_CONTROL, B_CONTROL, Y_TELEGRAM = 0, 1, 3, 5, 6, 7
STX_I, DLE_I, NAK_I = 0, 1, 3


def tap_frame(frame):
    out = bytearray()
    for i in range(0, len(frame), 64):
        part = frame[i : i + 64]
        out.append(TAP_RX | (len(part) - 1) << 2)
        out.extend(part)
    # 10 ms of silence ends the frame at every baud rate from 9600 up.
    out.append(TAP_SILENCE | 10 << 2)
    return bytes(out)


def write_rtu_tap(frames):
    for name, frame in frames.items():
        m = re.fullmatch(r"(.*)-request", name)
        if not m:
            continue
        answers = [f for other, f in frames.items()
                   if other != name and other.startswith(m.group(1) + "-")
                   and other.endswith(("-response", "-exception"))]
        script = bytearray([0x01 | 2 << 4])  # 9600 Bd, answer timeout 1 s
        for answer in answers:
            script += tap_frame(frame) + tap_frame(answer)
        # A request nobody answers, then the deadlines.
        script += tap_frame(frame) + bytes([TAP_TIMEOUT, TAP_TIMEOUT])
        write("rtu_tap", m.group(1), bytes(script))


def y_telegram(side_b, user):
    out = bytearray()
    for i in range(0, len(user), 32):
        part = user[i : i + 32]
        out.append(Y_TELEGRAM | ((len(part) - 1) << 1 | int(side_b)) << 3)
        out.extend(part)
    return bytes(out)


def y_exchange(sender_b, user, ack=DLE_I):
    sender, receiver = (B_CONTROL, A_CONTROL) if sender_b else (A_CONTROL, B_CONTROL)
    return (bytes([sender | STX_I << 3, receiver | DLE_I << 3]) + y_telegram(sender_b, user)
            + bytes([receiver | ack << 3]))


def write_tap3964(vectors):
    for name, wire in vectors.items():
        if not name.startswith("3964") or "bad" in name:
            continue
        setup = 0 if name.startswith("3964r") else 1
        user = (wire[:-3] if setup == 0 else wire[:-2]).replace(b"\x10\x10", b"\x10")
        write("tap3964", name + "-both-sides",
              bytes([setup]) + y_exchange(False, user) + y_exchange(True, user)
              + bytes([Y_TIMEOUT]))
        write("tap3964", name + "-nak-repeated",
              bytes([setup]) + y_exchange(False, user, NAK_I) + y_exchange(False, user)
              + bytes([Y_TIMEOUT]))
    # Both partners send STX; B answers DLE (A has the higher priority), A's telegram follows.
    write("tap3964", "conflict",
          bytes([0, A_CONTROL | STX_I << 3, B_CONTROL | STX_I << 3, B_CONTROL | DLE_I << 3])
          + y_telegram(False, b"AB") + bytes([B_CONTROL | DLE_I << 3, Y_TIMEOUT]))


def write_marks(frames):
    # What a tty opened with INPCK|PARMRK delivers: FF doubled, FF 00 x a faulty character x,
    # FF 00 00 a BREAK. The first byte chooses the fuzzer's chunk size.
    for name, frame in sorted(frames.items())[:4]:
        write("marks", name, frame.replace(b"\xff", b"\xff\xff"))
    write("marks", "all-marks", b"\x03\x01\xff\xff\x02\xff\x00\x41\x05\xff\x00\x00\x06\xff")


def write(target, name, data):
    folder = SEEDS / target
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_bytes(data)


def main():
    vectors = {p.stem: parse(p) for p in sorted(VECTORS.glob("*.hex"))}
    frames = {}
    for name, data in vectors.items():
        if name.startswith("3964"):
            write_3964(name, data)
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
    write_telegrams()
    write_marks(frames)
    write_rtu_tap(frames)
    write_tap3964({n: d for n, d in vectors.items() if n.startswith("3964")})
    # MBAP frames of the request PDUs.
    stream = b""
    for number, (name, frame) in enumerate(sorted(frames.items())):
        if name.endswith("-request"):
            adu = mbap(number, frame[0], frame[1:-2])
            write("mbap", name, adu)
            stream += adu
    write("mbap", "pipelined-requests", stream)
    write("mbap", "read-bad-protocol", b"\x00\x01\x00\x01\x00\x06\x01\x03\x00\x00\x00\x01")
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
