"""Mutual TLS and access control over real zenoh sessions on loopback.

Certificates come from ``deploy/make-certs.sh`` (openssl) in a temporary directory. The router
(the fusion center) admits only TLS peers with a certificate of the network's CA, and its access
control lets only member common names publish detections or read tracks.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import subprocess
import threading
import time
from pathlib import Path

import msgpack
import pytest
import zenoh

from fusion_center.service import FusionConfig, FusionService
from node_agent.agent import AgentConfig, NodeAgent
from protocol import keys
from protocol.transport import FifoChannel, free_tcp_port
from sim_nodes.driver import SimulatedDriver
from sim_nodes.network import SimNetwork
from tests.waiting import wait_for as _wait_for
from uwbnet.config import ZenohModel, zenoh_config

pytestmark = [pytest.mark.integration, pytest.mark.security]

NET = "stest"
MAKE_CERTS = Path(__file__).parents[2] / "deploy" / "make-certs.sh"


@pytest.fixture(scope="module")
def certs(tmp_path_factory):  # type: ignore[no-untyped-def]
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: cannot make test certificates")
    d = tmp_path_factory.mktemp("certs")
    names = ["fusion", "bat1", "viewer", "intruder"]
    subprocess.run([str(MAKE_CERTS), str(d / "net"), *names], check=True, capture_output=True)
    subprocess.run([str(MAKE_CERTS), str(d / "rogue"), "bat1"], check=True, capture_output=True)
    return d


def _tls(certs: Path, name: str, ca: str = "net") -> dict[str, str]:
    base = certs / ca
    return {
        "ca": str(base / "ca.pem"),
        "cert": str(base / f"{name}.pem"),
        "key": str(base / f"{name}.key"),
    }


def test_only_member_certificates_can_publish_detections_or_read_tracks(certs):
    ep = f"tls/127.0.0.1:{free_tcp_port()}"
    router_model = ZenohModel(
        mode="router",
        listen=[ep],
        tls=_tls(certs, "fusion"),
        access={"members": ["fusion", "bat1"], "viewers": ["viewer"]},
    )

    def client(name: str, ca: str = "net") -> zenoh.Session:
        return zenoh.open(
            zenoh_config(ZenohModel(mode="client", connect=[ep], tls=_tls(certs, name, ca)), NET)
        )

    network = SimNetwork("foyer3", seed=2)
    start = time.time() + 0.3
    with contextlib.ExitStack() as stack:
        rs = stack.enter_context(zenoh.open(zenoh_config(router_model, NET)))
        fusion = FusionService(rs, FusionConfig(net=NET), epoch=start)
        fusion.start()
        stack.callback(fusion.stop)
        # A member node agent works as without TLS.
        ns = stack.enter_context(client("bat1"))
        drv = stack.enter_context(SimulatedDriver(network, "bat1", start=start))
        agent = NodeAgent(ns, drv, AgentConfig(node="bat1", net=NET, publish_ir=False))
        agent.start()
        stack.callback(agent.stop)
        _wait_for(lambda: fusion.core.counters.updates > 20, 15.0, "tracks from the member node")

        # No certificate (only the CA, as a curious laptop on the wifi would have), a plain
        # TCP client, and a certificate of another CA: the router refuses the link.
        no_cert = zenoh.Config()
        no_cert.insert_json5("mode", '"client"')
        no_cert.insert_json5("connect/endpoints", json.dumps([ep]))
        no_cert.insert_json5(
            "transport/link/tls", json.dumps({"root_ca_certificate": _tls(certs, "bat1")["ca"]})
        )
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(no_cert).close()
        plain = zenoh.Config()
        plain.insert_json5("mode", '"client"')
        plain.insert_json5("connect/endpoints", json.dumps([ep.replace("tls/", "tcp/")]))
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(plain).close()
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            client("bat1", ca="rogue").close()

        # A certificate of the CA whose name is not a member: admitted to the link, but it can
        # neither inject detections nor read tracks.
        seen: FifoChannel[bytes] = FifoChannel(10000)
        for name in ("intruder", "viewer"):
            s = stack.enter_context(client(name))
            got: FifoChannel[bytes] = FifoChannel(10000)
            sub = s.declare_subscriber(
                keys.fusion_key(NET, "tracks"), lambda x, got=got: got.put(x.payload.to_bytes())
            )
            stack.callback(sub.undeclare)
            threading.Event().wait(1.0)
            before = fusion.decode_errors
            fake = msgpack.packb({"v": 1, "kind": "detections", "src": name, "seq": 0})
            s.put(keys.node_key(NET, name, "det"), fake)
            threading.Event().wait(1.0)
            # The garbage would be counted as a decode error had it reached the fusion center.
            assert fusion.decode_errors == before, f"{name} published detections"
            assert name not in fusion.snapshot()[1]
            if name == "intruder":
                assert len(got) == 0, "a non-member read tracks"
            else:
                assert len(got) > 10, "the viewer could not read tracks"
            seen.put(name.encode())
        assert len(seen) == 2
