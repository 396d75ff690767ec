#!/usr/bin/env python3
"""Makes the damaged model files of the red-team suite from a good one (tests/redteam/redteam.sh).

  modeltool.py overflow SRC_STEM DST_STEM   head.weight = 3e38: finite weights, every output
                                            overflows to infinity
  modeltool.py number SRC_STEM DST_STEM     half_u_mm = 1e400 in the metadata (no double holds it)

The copy's metadata names its own weight file, and its weight fingerprint (version 2) is updated,
so only the intended damage is there.
"""
import json
import re
import struct
import sys


def fnv1a64(data):
    h = 14695981039346656037
    for b in data:
        h ^= b
        h = (h * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def main():
    cmd, src, dst = sys.argv[1:4]
    weights = bytearray(open(src + ".safetensors", "rb").read())
    meta_text = open(src + ".json").read()
    if cmd == "overflow":
        n = struct.unpack("<Q", weights[:8])[0]
        header = json.loads(weights[8:8 + n])
        lo, hi = header["head.weight"]["data_offsets"]
        for i in range(8 + n + lo, 8 + n + hi, 4):
            weights[i:i + 4] = struct.pack("<f", 3e38)
    elif cmd != "number":
        sys.exit(__doc__)
    meta = json.loads(meta_text)
    meta["weights"] = dst.split("/")[-1] + ".safetensors"
    if "weights_fingerprint" in meta:
        meta["weights_fingerprint"] = "fnv1a64:%016x" % fnv1a64(bytes(weights))
    text = json.dumps(meta, indent=2)
    if cmd == "number":
        text = re.sub(r'"half_u_mm": [^,\n]+', '"half_u_mm": 1e400', text)
    open(dst + ".safetensors", "wb").write(weights)
    open(dst + ".json", "w").write(text + "\n")


if __name__ == "__main__":
    main()
