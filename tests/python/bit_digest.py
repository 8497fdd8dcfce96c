"""The canonical bytes of nested results, for digests that compare bits across builds and machines
(isa_digest.py, det_inputs_digest.py), and this processor's feature flags (which builds and kernels
it can run: test_isa_bits.py, test_lanes.py)."""
from __future__ import annotations

import hashlib

import numpy as np


def feed(h, value) -> None:
    """Feeds a canonical form of value to hash h: floats by their bits, arrays by dtype, shape
    and bytes, mappings in key order."""
    if isinstance(value, dict):
        for k in sorted(value):
            h.update(f"<{k}>".encode())
            feed(h, value[k])
    elif isinstance(value, (list, tuple)):
        h.update(f"[{len(value)}".encode())
        for v in value:
            feed(h, v)
    elif isinstance(value, np.ndarray):
        h.update(f"{value.dtype.str}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, float):
        h.update(value.hex().encode())
    else:
        h.update(repr(value).encode())


def sha256(value) -> str:
    """The sha-256 (hex) of value's canonical form."""
    h = hashlib.sha256()
    feed(h, value)
    return h.hexdigest()


def cpu_flags() -> set:
    """The feature flags of this processor (/proc/cpuinfo's first ``flags`` line)."""
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    return set()
