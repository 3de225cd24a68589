"""Key expressions of the contract (PROTOCOL.md, "Key expressions"): builders and a parser."""

from __future__ import annotations

import dataclasses

from protocol.errors import KeyExprError
from protocol.schema import ID_RE

PREFIX = "uwbnet"
#: Leaves under ``uwbnet/{net}/node/{node}/`` and the message kind each carries.
NODE_LEAVES = {"info": "node_info", "ir": "ir", "det": "detections", "status": "status"}
#: Leaves under ``uwbnet/{net}/fusion/``.
FUSION_LEAVES = {"tracks": "tracks", "poses": "poses", "image": "image", "map": "map"}


def _check_id(what: str, value: str) -> str:
    if not ID_RE.match(value):
        raise KeyExprError(f"{what} {value!r} does not match [A-Za-z0-9_-]+")
    return value


def node_key(net: str, node: str, leaf: str) -> str:
    """``uwbnet/{net}/node/{node}/{leaf}``, leaf one of info, ir, det, status."""
    if leaf not in NODE_LEAVES:
        raise KeyExprError(f"unknown node leaf {leaf!r}")
    return f"{PREFIX}/{_check_id('net', net)}/node/{_check_id('node', node)}/{leaf}"


def all_nodes_key(net: str, leaf: str) -> str:
    """Wildcard over every node's ``leaf``: ``uwbnet/{net}/node/*/{leaf}``."""
    if leaf not in NODE_LEAVES:
        raise KeyExprError(f"unknown node leaf {leaf!r}")
    return f"{PREFIX}/{_check_id('net', net)}/node/*/{leaf}"


def alive_key(net: str, node: str) -> str:
    """Liveliness token key of a node agent or service: ``uwbnet/{net}/alive/{node}``."""
    return f"{PREFIX}/{_check_id('net', net)}/alive/{_check_id('node', node)}"


def all_alive_key(net: str) -> str:
    return f"{PREFIX}/{_check_id('net', net)}/alive/*"


def schedule_key(net: str) -> str:
    return f"{PREFIX}/{_check_id('net', net)}/tdma/schedule"


def fusion_key(net: str, leaf: str) -> str:
    """``uwbnet/{net}/fusion/{leaf}``, leaf one of tracks, poses, image, map."""
    if leaf not in FUSION_LEAVES:
        raise KeyExprError(f"unknown fusion leaf {leaf!r}")
    return f"{PREFIX}/{_check_id('net', net)}/fusion/{leaf}"


def cell_tracks_key(net: str, cell: int) -> str:
    """``uwbnet/{net}/fusion/cell/{cell}/tracks``: a sharded fusion center's cell worker's
    tracks (its own labels), merged by the gateway onto ``fusion/tracks``."""
    if cell < 0:
        raise KeyExprError(f"cell index must be >= 0, not {cell}")
    return f"{PREFIX}/{_check_id('net', net)}/fusion/cell/{int(cell)}/tracks"


def all_cell_tracks_key(net: str) -> str:
    return f"{PREFIX}/{_check_id('net', net)}/fusion/cell/*/tracks"


def truth_key(net: str) -> str:
    return f"{PREFIX}/{_check_id('net', net)}/sim/truth"


def all_key(net: str) -> str:
    """Everything of one network: ``uwbnet/{net}/**``."""
    return f"{PREFIX}/{_check_id('net', net)}/**"


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class ParsedKey:
    """A concrete key split into its parts. ``node`` is set for node and alive keys."""

    net: str
    area: str  # node | alive | tdma | fusion | sim
    node: str | None
    leaf: str  # info, ir, det, status, schedule, tracks, ..., truth; "" for alive
    kind: str | None  # the message kind carried, None for liveliness


def parse_key(key: str) -> ParsedKey:
    """Parse a concrete uwbnet key expression; raise :class:`KeyExprError` if it is not one."""
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != PREFIX:
        raise KeyExprError(f"not a uwbnet key: {key!r}")
    net = _check_id("net", parts[1])
    area, rest = parts[2], parts[3:]
    if area == "node" and len(rest) == 2 and rest[1] in NODE_LEAVES:
        node = _check_id("node", rest[0])
        return ParsedKey(net=net, area=area, node=node, leaf=rest[1], kind=NODE_LEAVES[rest[1]])
    if area == "alive" and len(rest) == 1:
        return ParsedKey(net=net, area=area, node=_check_id("node", rest[0]), leaf="", kind=None)
    if area == "tdma" and rest == ["schedule"]:
        return ParsedKey(net=net, area=area, node=None, leaf="schedule", kind="tdma_schedule")
    if area == "fusion" and len(rest) == 1 and rest[0] in FUSION_LEAVES:
        return ParsedKey(net=net, area=area, node=None, leaf=rest[0], kind=FUSION_LEAVES[rest[0]])
    if area == "sim" and rest == ["truth"]:
        return ParsedKey(net=net, area=area, node=None, leaf="truth", kind="truth")
    raise KeyExprError(f"not a uwbnet key: {key!r}")


def topic_for(net: str, msg_kind: str, src: str) -> str:
    """The key (and MCAP topic) on which a message of ``msg_kind`` from ``src`` travels."""
    for leaf, kind in NODE_LEAVES.items():
        if kind == msg_kind:
            return node_key(net, src, leaf)
    for leaf, kind in FUSION_LEAVES.items():
        if kind == msg_kind:
            return fusion_key(net, leaf)
    if msg_kind == "tdma_schedule":
        return schedule_key(net)
    if msg_kind == "truth":
        return truth_key(net)
    raise KeyExprError(f"no key for kind {msg_kind!r}")
