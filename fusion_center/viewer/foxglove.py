"""Foxglove-compatible ``/viz/...`` channels of a recording (PROTOCOL.md, "Recordings").

Foxglove and Lichtblick cannot decode msgpack, so the recorder adds JSON channels in Foxglove's
published JSON schemas (vendored in ``foxglove_schemas/``, MIT licence, from the
``@foxglove/schemas`` package): a recording then opens with a meaningful 3-D panel.

==================  ======================  ==========================================
topic               schema                  what
==================  ======================  ==========================================
``/viz/walls``      ``foxglove.SceneUpdate``  floor-plan walls as boxes (once a second)
``/viz/sensors``    ``foxglove.SceneUpdate``  sensors: box, boresight arrow, label
``/viz/tracks``     ``foxglove.SceneUpdate``  tracks: a person-sized cylinder, label, tail
``/viz/truth``      ``foxglove.SceneUpdate``  simulator truth: small spheres
``/viz/image``      ``foxglove.Grid``         ``image`` messages (FLOAT32 cells)
==================  ======================  ==========================================

Everything is in frame ``world`` (PROTOCOL.md's world frame, metres). :class:`FoxgloveScene`
is pure: messages in, ``(topic, schema, document)`` out; the recorder writes them.
"""

from __future__ import annotations

import base64
import json
import math
from collections import deque
from collections.abc import Iterable, Sequence
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from protocol import Image, NodeInfo, Tracks, Truth

FRAME = "world"
SCENE = "foxglove.SceneUpdate"
GRID = "foxglove.Grid"
FLOAT32 = 7  # foxglove.NumericType


@cache
def foxglove_schema(name: str) -> bytes:
    """The vendored JSON schema ``name`` (``foxglove.SceneUpdate`` or ``foxglove.Grid``)."""
    return (
        resources.files("fusion_center.viewer") / "foxglove_schemas" / f"{name}.json"
    ).read_bytes()


def _time(t: float) -> dict[str, int]:
    ns = max(0, round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _pose(x: float, y: float, z: float = 0.0, yaw: float = 0.0) -> dict[str, Any]:
    return {
        "position": {"x": float(x), "y": float(y), "z": float(z)},
        "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)},
    }


def _colour(r: float, g: float, b: float, a: float = 1.0) -> dict[str, float]:
    return {"r": r, "g": g, "b": b, "a": a}


def _vec(x: float, y: float, z: float) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "z": float(z)}


_PRIMITIVES = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")


def _entity(t: float, eid: str, lifetime: float = 0.0, **prims: list[dict[str, Any]]) -> dict:
    ent: dict[str, Any] = {
        "timestamp": _time(t),
        "frame_id": FRAME,
        "id": eid,
        "lifetime": _time(lifetime),
        "frame_locked": False,
        "metadata": [],
    }
    for kind in (
        "arrows",
        "cubes",
        "spheres",
        "cylinders",
        "lines",
        "triangles",
        "texts",
        "models",
    ):
        ent[kind] = prims.get(kind, [])
    return ent


def _text(t: str, x: float, y: float, z: float, colour: dict[str, float]) -> dict[str, Any]:
    return {
        "pose": _pose(x, y, z),
        "billboard": True,
        "font_size": 14.0,
        "scale_invariant": True,
        "color": colour,
        "text": t,
    }


_PALETTE = [
    (0.31, 0.76, 0.97),
    (0.94, 0.38, 0.57),
    (0.68, 0.84, 0.51),
    (1.0, 0.84, 0.31),
    (0.73, 0.41, 0.78),
    (0.30, 0.71, 0.67),
]


class FoxgloveScene:
    """Turns the network's messages into Foxglove documents for the ``/viz`` channels.

    Parameters
    ----------
    walls : segments ``[x1, y1, x2, y2]`` (m) of the floor plan.
    wall_height : drawn height of a wall, m.
    tail_seconds : length of a track's tail, s.
    static_period : walls and sensors are re-sent this often (s), so that a viewer that seeks
        into the middle of a recording still shows them.
    period : tracks and truth are written at most this often (s): a 3-D panel needs no more
        than 10 Hz, and the recorder thread shares the fusion process.
    """

    def __init__(
        self,
        walls: Iterable[Sequence[float]] = (),
        *,
        wall_height: float = 2.5,
        tail_seconds: float = 3.0,
        static_period: float = 1.0,
        period: float = 0.1,
    ) -> None:
        self.walls = [[float(v) for v in w] for w in walls]
        self.wall_height, self.tail_seconds = wall_height, tail_seconds
        self.static_period, self.period = static_period, period
        self._last: dict[str, float] = {}
        self.infos: dict[str, NodeInfo] = {}
        self._tails: dict[int, deque[tuple[float, float, float]]] = {}
        self._last_static = -math.inf

    def on_message(self, msg: Any) -> list[tuple[str, str, dict[str, Any]]]:
        """The ``(topic, schema name, document)`` triples to write after ``msg``."""
        out: list[tuple[str, str, dict[str, Any]]] = []
        if isinstance(msg, NodeInfo):
            changed = self.infos.get(msg.src) != msg
            self.infos[msg.src] = msg
            if changed:
                out.append(("/viz/sensors", SCENE, self.sensors(msg.t)))
        elif isinstance(msg, Tracks) and self._due("tracks", msg.t):
            out.append(("/viz/tracks", SCENE, self.tracks(msg)))
        elif isinstance(msg, Truth) and self._due("truth", msg.t):
            out.append(("/viz/truth", SCENE, self.truth(msg)))
        elif isinstance(msg, Image):
            out.append(("/viz/image", GRID, self.grid(msg)))
        t = float(msg.t)
        if t - self._last_static >= self.static_period:
            self._last_static = t
            if self.walls:
                out.append(("/viz/walls", SCENE, self.walls_update(t)))
            if self.infos and not isinstance(msg, NodeInfo):
                out.append(("/viz/sensors", SCENE, self.sensors(t)))
        return out

    def _due(self, stream: str, t: float) -> bool:
        if t - self._last.get(stream, -math.inf) < self.period - 1e-9:
            return False
        self._last[stream] = t
        return True

    def walls_update(self, t: float) -> dict[str, Any]:
        """``foxglove.SceneUpdate``: one box per wall segment (0.1 m thick)."""
        cubes = []
        for x1, y1, x2, y2 in self.walls:
            length = math.hypot(x2 - x1, y2 - y1)
            yaw = math.atan2(y2 - y1, x2 - x1)
            cubes.append(
                {
                    "pose": _pose((x1 + x2) / 2, (y1 + y2) / 2, self.wall_height / 2, yaw),
                    "size": _vec(length, 0.1, self.wall_height),
                    "color": _colour(0.75, 0.77, 0.8, 0.35),
                }
            )
        return {"deletions": [], "entities": [_entity(t, "walls", cubes=cubes)]}

    def sensors(self, t: float) -> dict[str, Any]:
        """``foxglove.SceneUpdate``: each known node as a box, a boresight arrow and its id."""
        ents = []
        green = _colour(0.24, 0.86, 0.52)
        for node, info in sorted(self.infos.items()):
            x, y, z, yaw = info.pose
            bore = yaw + next((a.boresight for a in info.antennas.values() if a.tx), 0.0)
            ents.append(
                _entity(
                    t,
                    f"sensor/{node}",
                    cubes=[
                        {"pose": _pose(x, y, z, yaw), "size": _vec(0.2, 0.6, 0.2), "color": green}
                    ],
                    arrows=[
                        {
                            "pose": _pose(x, y, z, bore),
                            "shaft_length": 0.5,
                            "shaft_diameter": 0.04,
                            "head_length": 0.15,
                            "head_diameter": 0.12,
                            "color": green,
                        }
                    ],
                    texts=[_text(node, x, y, z + 0.4, _colour(1, 1, 1))],
                )
            )
        return {"deletions": [], "entities": ents}

    def tracks(self, msg: Tracks) -> dict[str, Any]:
        """``foxglove.SceneUpdate``: each track as a 1.7 m cylinder with its id and tail.

        Entities live 0.5 s: a track that is no longer reported disappears.
        """
        ents = []
        live = set()
        for tr in msg.tracks:
            live.add(tr.id)
            tail = self._tails.setdefault(tr.id, deque())
            tail.append((msg.t, tr.x, tr.y))
            while tail and tail[0][0] < msg.t - self.tail_seconds:
                tail.popleft()
            r, g, b = _PALETTE[tr.id % len(_PALETTE)]
            col = _colour(r, g, b, 0.9)
            ents.append(
                _entity(
                    msg.t,
                    f"track/{tr.id}",
                    lifetime=0.5,
                    cylinders=[
                        {
                            "pose": _pose(tr.x, tr.y, 0.85),
                            "size": _vec(0.5, 0.5, 1.7),
                            "bottom_scale": 1.0,
                            "top_scale": 1.0,
                            "color": col,
                        }
                    ],
                    lines=[
                        {
                            "type": 0,  # LINE_STRIP
                            "pose": _pose(0.0, 0.0),
                            "thickness": 0.05,
                            "scale_invariant": False,
                            "points": [_vec(x, y, 0.05) for _, x, y in tail],
                            "color": col,
                            "colors": [],
                            "indices": [],
                        }
                    ],
                    texts=[_text(f"{tr.id}", tr.x, tr.y, 2.0, _colour(1, 1, 1))],
                )
            )
        for tid in [k for k in self._tails if k not in live]:
            del self._tails[tid]
        return {"deletions": [], "entities": ents}

    def truth(self, msg: Truth) -> dict[str, Any]:
        """``foxglove.SceneUpdate``: the simulator's true positions as small white spheres."""
        spheres = [
            {
                "pose": _pose(p.x, p.y, 0.1),
                "size": _vec(0.2, 0.2, 0.2),
                "color": _colour(1, 1, 1, 0.8),
            }
            for p in msg.targets
        ]
        return {"deletions": [], "entities": [_entity(msg.t, "truth", 0.2, spheres=spheres)]}

    def grid(self, msg: Image) -> dict[str, Any]:
        """``foxglove.Grid`` of an ``image`` message: FLOAT32 cells, row 0 at ``y0``.

        The grid's origin is the corner of pixel (0, 0): ``(x0 - dx/2, y0 - dy/2)``.
        """
        img = np.ascontiguousarray(msg.img, dtype="<f4")
        nx = img.shape[1]
        return {
            "timestamp": _time(msg.t),
            "frame_id": FRAME,
            "pose": _pose(msg.x0 - msg.dx / 2, msg.y0 - msg.dy / 2, 0.02),
            "column_count": int(nx),
            "cell_size": {"x": float(msg.dx), "y": float(msg.dy)},
            "row_stride": int(nx * 4),
            "cell_stride": 4,
            "fields": [{"name": msg.method or "value", "offset": 0, "type": FLOAT32}],
            "data": base64.b64encode(img.tobytes()).decode("ascii"),
        }


def dumps(doc: dict[str, Any]) -> bytes:
    """A ``/viz`` document as compact JSON bytes (the channel's ``json`` encoding)."""
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()
