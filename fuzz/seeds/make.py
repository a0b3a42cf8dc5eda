#!/usr/bin/env python3
"""Writes small seed files for the texture targets that the project has no
files of: a baseline-structured and a progressive greyscale JPEG (every
coefficient zero, one-code Huffman tables, as core/tests/format_bounds.rs
builds them) and an uncompressed 4 x 2 RGB float OpenEXR. Usage: make.py DIR
(writes DIR/jpeg/*.jpg and DIR/exr/*.exr)."""
import os
import struct
import sys


def seg(code, body):
    return bytes([0xFF, code]) + struct.pack(">H", len(body) + 2) + body


def jpeg(w, h, sof, ac_scans):
    f = b"\xff\xd8" + seg(0xDB, b"\x00" + b"\x01" * 64)
    f += seg(sof, b"\x08" + struct.pack(">HH", h, w) + b"\x01\x01\x11\x00")
    one = bytes([0, 1] + [0] * 15)  # class byte set below; one code of length 1
    for cls in (0x00, 0x10):
        f += seg(0xC4, bytes([cls]) + one[1:] + b"\x00")
    blocks = ((w + 7) // 8) * ((h + 7) // 8)
    data = b"\x00" * ((blocks * (2 if sof == 0xC0 else 1) + 7) // 8)
    if sof == 0xC0:
        f += seg(0xDA, b"\x01\x01\x00\x00\x3f\x00") + data
    else:
        f += seg(0xDA, b"\x01\x01\x00\x00\x00\x00") + data
        for _ in range(ac_scans):
            f += seg(0xDA, b"\x01\x01\x00\x01\x3f\x00") + data
    return f + b"\xff\xd9"


def attr(name, typ, value):
    return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value


def exr(w, h):
    chans = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in "BGR") + b"\0"
    box = struct.pack("<iiii", 0, 0, w - 1, h - 1)
    head = b"\x76\x2f\x31\x01" + struct.pack("<i", 2)
    head += attr("channels", "chlist", chans)
    head += attr("compression", "compression", b"\0")
    head += attr("dataWindow", "box2i", box)
    head += attr("displayWindow", "box2i", box)
    head += attr("lineOrder", "lineOrder", b"\0")
    head += attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
    head += attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0))
    head += attr("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\0"
    lines = []
    for y in range(h):
        data = b"".join(struct.pack("<f", (c + 1) * 0.25 + 0.1 * x) for c in range(3) for x in range(w))
        lines.append(struct.pack("<ii", y, len(data)) + data)
    offset = len(head) + 8 * h
    table = b""
    for line in lines:
        table += struct.pack("<Q", offset)
        offset += len(line)
    return head + table + b"".join(lines)


out = sys.argv[1]
os.makedirs(os.path.join(out, "jpeg"), exist_ok=True)
os.makedirs(os.path.join(out, "exr"), exist_ok=True)
open(os.path.join(out, "jpeg", "baseline.jpg"), "wb").write(jpeg(16, 8, 0xC0, 0))
open(os.path.join(out, "jpeg", "progressive.jpg"), "wb").write(jpeg(24, 16, 0xC2, 2))
open(os.path.join(out, "exr", "rgb.exr"), "wb").write(exr(4, 2))
