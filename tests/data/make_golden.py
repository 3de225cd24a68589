"""Write the golden payloads of the wire contract v1, one file per message kind.

The bytes are built by hand with ``msgpack`` and ``struct`` only, exactly as
``/work/shared/PROTOCOL.md`` describes them, without importing ``protocol/``: the files are an
independent statement of the contract, as an outside tool would write it. Key order is the
header ``v, kind, src, seq, t`` and then the fields in PROTOCOL.md order; floats are float64,
arrays are ``{"dtype", "shape", "data"}`` maps in C order, little endian.

Run ``python tests/data/make_golden.py`` to rewrite ``tests/data/golden/*.msgpack``; the
golden test checks that the files on disk equal what this script builds.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import msgpack

GOLDEN_DIR = Path(__file__).resolve().parent / "golden"

_FORMATS = {"<f4": "f", "<f8": "d", "<i4": "i", "<u2": "H"}


def array(dtype: str, shape: list[int], values: list[Any]) -> dict[str, Any]:
    """A wire array map; ``values`` flat in C order (complex values for ``<c8``)."""
    assert len(values) == math.prod(shape)
    if dtype == "<c8":
        flat = [part for z in values for part in (z.real, z.imag)]
        data = struct.pack(f"<{len(flat)}f", *flat)
    else:
        data = struct.pack(f"<{len(values)}{_FORMATS[dtype]}", *values)
    return {"dtype": dtype, "shape": shape, "data": data}


def header(kind: str, src: str, seq: int, t: float) -> dict[str, Any]:
    return {"v": 1, "kind": kind, "src": src, "seq": seq, "t": t}


# Sample values are exact in float32, so a reader can check them without rounding.
IR_F4 = [[0.25 * k - 2.0 for k in range(16)], [float((-1) ** k) * 0.5 * k for k in range(16)]]
IR_C8 = [
    [complex(0.5 * k, -0.25 * k) for k in range(16)],
    [complex(1.0 - 0.125 * k, 0.0625 * k) for k in range(16)],
]


def messages() -> dict[str, dict[str, Any]]:
    """Golden file stem -> the msgpack map, keys in contract order."""
    two_pi = 2 * math.pi
    return {
        "node_info": header("node_info", "anchor1", 0, 100.0)
        | {
            "role": "anchor",
            "pose": [1.5, -2.25, 1.1, 0.7853981633974483],
            "mobile": False,
            "antennas": {
                "tx0": {
                    "pos": [0.0, 0.1, 0.0],
                    "tx": True,
                    "rx": False,
                    "boresight": 0.0,
                    "beamwidth": 1.5707963267948966,
                },
                "rx0": {
                    "pos": [0.0, -0.1, 0.0],
                    "tx": False,
                    "rx": True,
                    "boresight": 0.0,
                    "beamwidth": 1.5707963267948966,
                },
                "rx1": {
                    "pos": [0.0, -0.3, 0.0],
                    "tx": False,
                    "rx": True,
                    "boresight": 0.5,
                    "beamwidth": 1.5707963267948966,
                },
            },
            "radar": {
                "fs": 13.312e9,
                "n": 16,
                "t0": -1.5e-9,
                "f_low": 3.5e9,
                "f_high": 10.0e9,
                "rate": 100.0,
            },
        },
        "node_info_dw1000": header("node_info", "bat2", 3, 101.25)
        | {
            "role": "bat",
            "pose": [0.0, 0.0, 0.3, -1.0],
            "mobile": True,
            "antennas": {
                "a": {
                    "pos": [0.05, 0.0, 0.0],
                    "tx": True,
                    "rx": True,
                    "boresight": 0.0,
                    "beamwidth": two_pi,
                },
            },
            "radar": {
                "fs": 1.0016e9,
                "n": 16,
                "t0": 0.0,
                "f_low": 6.2396e9,
                "f_high": 6.7396e9,
                "rate": 50.0,
                "fc": 6.4896e9,
            },
        },
        "ir": header("ir", "anchor1", 42, 100.5)
        | {
            "tx": "anchor1/tx0",
            "rx": ["rx0", "rx1"],
            "slot": 2,
            "frame": 1234,
            "h": array("<f4", [2, 16], IR_F4[0] + IR_F4[1]),
        },
        "ir_c8": header("ir", "bat2", 7, 101.5)
        | {
            "tx": "anchor1/tx0",
            "rx": ["a", "b"],
            "slot": 0,
            "frame": 99,
            "h": array("<c8", [2, 16], IR_C8[0] + IR_C8[1]),
            "pose": [2.0, 3.0, 0.3, 1.25],
        },
        "detections": header("detections", "anchor1", 43, 100.5)
        | {
            "tx": "anchor1/tx0",
            "frame": 1234,
            "ranges": {"rx0": [3.25, 7.5], "rx1": [4.125]},
            "amplitudes": {"rx0": [0.75, 0.125], "rx1": [0.5]},
            "positions": array("<f8", [2, 2], [1.0, 2.0, -3.5, 4.25]),
            "cov": array("<f8", [2, 2, 2], [0.01, 0.002, 0.002, 0.04, 0.09, 0.0, 0.0, 0.16]),
        },
        "status": header("status", "anchor1", 9, 110.0)
        | {
            "uptime": 3600.5,
            "acquired": 360050,
            "published": 360000,
            "dropped": 50,
            "late_slots": 3,
            "decode_errors": 1,
            "cpu": 0.375,
        },
        "tdma_schedule": header("tdma_schedule", "fusion", 1, 99.0)
        | {
            "frame_period": 0.02,
            "epoch": 98.0,
            "slots": [
                {"slot": 0, "tx": "anchor1/tx0", "start": 0.0, "duration": 0.005},
                {"slot": 1, "tx": "bat2/a", "start": 0.005, "duration": 0.005},
            ],
        },
        "tracks": header("tracks", "fusion", 500, 100.52)
        | {
            "tracks": [
                {
                    "id": 17,
                    "x": 4.5,
                    "y": 3.25,
                    "vx": 0.5,
                    "vy": -0.25,
                    "cov": [
                        [0.04, 0.01, 0.0, 0.0],
                        [0.01, 0.09, 0.0, 0.0],
                        [0.0, 0.0, 0.04, 0.01],
                        [0.0, 0.0, 0.01, 0.09],
                    ],
                    "w": 0.95,
                },
            ],
            "n_estimate": 1.05,
        },
        "poses": header("poses", "fusion", 501, 100.52)
        | {
            "poses": {
                "bat2": {
                    "pose": [2.0, 3.0, 0.3, 1.25],
                    "cov": [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.0025]],
                    "los": {"anchor1": True, "anchor3": False},
                },
            },
        },
        "image": header("image", "fusion", 502, 100.54)
        | {
            "x0": -1.0,
            "y0": 0.5,
            "dx": 0.25,
            "dy": 0.5,
            "method": "kirchhoff",
            "img": array("<f4", [2, 3], [0.0, 0.5, 1.0, 0.25, 0.75, 0.125]),
        },
        "map": header("map", "fusion", 7, 100.6)
        | {
            "robot": "robot",
            "origin": [2.25, 0.75, 0.0, 0.0],
            "walls": array("<f8", [2, 4], [0.0, 0.0, 9.0, 0.0, 9.0, 0.0, 9.0, 8.0]),
            "corners": array("<f8", [1, 2], [9.0, 0.0]),
            "points": array("<f8", [0, 2], []),
        },
        "truth": header("truth", "sim", 12, 100.5)
        | {
            "targets": [
                {"id": 1, "x": 4.5, "y": 3.25, "vx": 0.5, "vy": -0.25},
                {"id": 2, "x": -1.0, "y": 6.0, "vx": 0.0, "vy": 1.0},
            ],
            "nodes": {"bat2": [2.0, 3.0, 0.3, 1.25]},
        },
    }


def payloads() -> dict[str, bytes]:
    """Golden file stem -> the payload bytes."""
    return {name: msgpack.packb(m, use_bin_type=True) for name, m in messages().items()}


def main() -> None:
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    for name, payload in payloads().items():
        (GOLDEN_DIR / f"{name}.msgpack").write_bytes(payload)
        print(f"{name}.msgpack: {len(payload)} bytes")


if __name__ == "__main__":
    main()
