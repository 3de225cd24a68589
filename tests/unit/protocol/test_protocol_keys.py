"""Key expressions (PROTOCOL.md, "Key expressions"): builders, parser and id checks."""

from __future__ import annotations

import pytest

from protocol import KeyExprError
from protocol import keys as k

# key -> (area, node, leaf, kind), straight from the PROTOCOL.md table with net "demo".
TABLE = {
    "uwbnet/demo/node/anchor1/info": ("node", "anchor1", "info", "node_info"),
    "uwbnet/demo/node/anchor1/ir": ("node", "anchor1", "ir", "ir"),
    "uwbnet/demo/node/anchor1/det": ("node", "anchor1", "det", "detections"),
    "uwbnet/demo/node/anchor1/status": ("node", "anchor1", "status", "status"),
    "uwbnet/demo/alive/anchor1": ("alive", "anchor1", "", None),
    "uwbnet/demo/tdma/schedule": ("tdma", None, "schedule", "tdma_schedule"),
    "uwbnet/demo/fusion/tracks": ("fusion", None, "tracks", "tracks"),
    "uwbnet/demo/fusion/poses": ("fusion", None, "poses", "poses"),
    "uwbnet/demo/fusion/image": ("fusion", None, "image", "image"),
    "uwbnet/demo/sim/truth": ("sim", None, "truth", "truth"),
}


def test_builders_produce_the_contract_keys() -> None:
    built = [
        k.node_key("demo", "anchor1", "info"),
        k.node_key("demo", "anchor1", "ir"),
        k.node_key("demo", "anchor1", "det"),
        k.node_key("demo", "anchor1", "status"),
        k.alive_key("demo", "anchor1"),
        k.schedule_key("demo"),
        k.fusion_key("demo", "tracks"),
        k.fusion_key("demo", "poses"),
        k.fusion_key("demo", "image"),
        k.truth_key("demo"),
    ]
    assert built == list(TABLE)


def test_wildcards() -> None:
    assert k.all_nodes_key("demo", "ir") == "uwbnet/demo/node/*/ir"
    assert k.all_alive_key("lab-2") == "uwbnet/lab-2/alive/*"
    assert k.all_key("demo") == "uwbnet/demo/**"


@pytest.mark.parametrize(
    ("kind", "src", "key"),
    [
        ("node_info", "n_1", "uwbnet/net/node/n_1/info"),
        ("ir", "n_1", "uwbnet/net/node/n_1/ir"),
        ("detections", "n_1", "uwbnet/net/node/n_1/det"),
        ("status", "n_1", "uwbnet/net/node/n_1/status"),
        ("tdma_schedule", "fusion", "uwbnet/net/tdma/schedule"),
        ("tracks", "fusion", "uwbnet/net/fusion/tracks"),
        ("poses", "fusion", "uwbnet/net/fusion/poses"),
        ("image", "fusion", "uwbnet/net/fusion/image"),
        ("truth", "sim", "uwbnet/net/sim/truth"),
    ],
)
def test_topic_for_each_kind(kind: str, src: str, key: str) -> None:
    assert k.topic_for("net", kind, src) == key
    assert k.parse_key(key).kind == kind


def test_topic_for_unknown_kind() -> None:
    with pytest.raises(KeyExprError, match="no key for kind 'foo'"):
        k.topic_for("demo", "foo", "n1")


@pytest.mark.parametrize("key", list(TABLE))
def test_parse_key_round_trips(key: str) -> None:
    area, node, leaf, kind = TABLE[key]
    parsed = k.parse_key(key)
    assert (parsed.net, parsed.area, parsed.node, parsed.leaf, parsed.kind) == (
        "demo",
        area,
        node,
        leaf,
        kind,
    )
    if area == "node":
        assert k.node_key(parsed.net, parsed.node, parsed.leaf) == key
    elif area == "alive":
        assert k.alive_key(parsed.net, parsed.node) == key
    else:
        assert k.topic_for(parsed.net, parsed.kind, "any") == key


@pytest.mark.parametrize("node", ["a", "Z9", "node-1_b", "0"])
def test_valid_ids(node: str) -> None:
    for leaf in k.NODE_LEAVES:
        assert k.parse_key(k.node_key(node, node, leaf)).node == node


BAD_IDS = ["a/b", "a b", "", "a*", "a.b", "ä", "a\n", "**"]


@pytest.mark.parametrize("bad", BAD_IDS)
def test_bad_node_id(bad: str) -> None:
    with pytest.raises(KeyExprError, match=r"node .* does not match \[A-Za-z0-9_-\]\+"):
        k.node_key("demo", bad, "ir")
    with pytest.raises(KeyExprError, match="does not match"):
        k.alive_key("demo", bad)


@pytest.mark.parametrize("bad", BAD_IDS)
def test_bad_net_id(bad: str) -> None:
    with pytest.raises(KeyExprError, match=r"net .* does not match"):
        k.node_key(bad, "n1", "ir")
    for build in (k.schedule_key, k.truth_key, k.all_key, k.all_alive_key):
        with pytest.raises(KeyExprError, match="does not match"):
            build(bad)
    with pytest.raises(KeyExprError, match="does not match"):
        k.fusion_key(bad, "tracks")


def test_unknown_leaves() -> None:
    with pytest.raises(KeyExprError, match="unknown node leaf 'detections'"):
        k.node_key("demo", "n1", "detections")
    with pytest.raises(KeyExprError, match="unknown node leaf 'x'"):
        k.all_nodes_key("demo", "x")
    with pytest.raises(KeyExprError, match="unknown fusion leaf 'truth'"):
        k.fusion_key("demo", "truth")


@pytest.mark.parametrize(
    "key",
    [
        "",
        "uwbnet",
        "uwbnet/demo",
        "other/demo/node/n1/ir",
        "uwbnet/demo/node/n1",
        "uwbnet/demo/node/n1/foo",
        "uwbnet/demo/node/n1/ir/extra",
        "uwbnet/demo/node/*/ir",
        "uwbnet/demo/node/a b/ir",
        "uwbnet/demo/node//ir",
        "uwbnet//node/n1/ir",
        "uwbnet/demo/alive",
        "uwbnet/demo/alive/a/b",
        "uwbnet/demo/tdma/frame",
        "uwbnet/demo/fusion/truth",
        "uwbnet/demo/sim/tracks",
        "uwbnet/demo/**",
        "/viz/scene",
    ],
)
def test_parse_key_rejects(key: str) -> None:
    with pytest.raises(KeyExprError) as info:
        k.parse_key(key)
    assert "\n" not in str(info.value)
