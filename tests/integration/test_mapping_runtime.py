"""The mapping runtime over real zenoh sessions: a robot's ir in, poses and maps out."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh

from fusion_center.mapping_service import MappingConfig, MappingService
from protocol import Ir, Map, Poses, decode, keys
from protocol.transport import FifoChannel, session_config
from sim_nodes.propagation import hybrid_channel, robot_dataset
from sim_nodes.robot_record import write_robot_recording
from sim_nodes.scene import load_scenario

pytestmark = pytest.mark.integration

NET = "maptest"


@pytest.fixture(scope="module")
def robot_messages(tmp_path_factory: pytest.TempPathFactory) -> list[object]:
    from protocol.recording import read_recording

    sc = load_scenario("corridor_L_sparse")
    ds = robot_dataset(sc, hybrid_channel(sc, np.random.default_rng(1)), stops=[0, 1])
    path = tmp_path_factory.mktemp("maprt") / "r.mcap"
    write_robot_recording(sc, ds, path, seed=1, net=NET)
    return [decode(r.payload) for r in read_recording(path)]


def test_robot_ir_gives_poses_and_maps(hub_endpoint: str, robot_messages: list[object]) -> None:
    info = robot_messages[0]
    irs = [m for m in robot_messages if isinstance(m, Ir)]
    got: FifoChannel[bytes] = FifoChannel(10000)
    with (
        zenoh.open(session_config(listen=[hub_endpoint])) as fs,
        zenoh.open(session_config(connect=[hub_endpoint])) as robot,
    ):
        service = MappingService(fs, MappingConfig(net=NET, particles=10, map_every=10))
        service.start()
        try:
            subs = [
                robot.declare_subscriber(
                    keys.fusion_key(NET, leaf), lambda s: got.put(s.payload.to_bytes())
                )
                for leaf in ("poses", "map")
            ]
            info_pub = robot.declare_publisher(keys.node_key(NET, info.src, "info"))
            ir_pub = robot.declare_publisher(keys.node_key(NET, info.src, "ir"))
            wait = threading.Event()
            deadline = time.monotonic() + 10
            # the service subscribes to the robot's ir once it has seen its node_info
            while service._robots.get(info.src) is None and time.monotonic() < deadline:
                info_pub.put(info.to_wire())
                wait.wait(0.1)
            wait.wait(0.3)
            for m in irs:
                ir_pub.put(m.to_wire())
                wait.wait(0.002)
            deadline = time.monotonic() + 60
            while service.poses_published < len(irs) - 4 and time.monotonic() < deadline:
                wait.wait(0.1)
            for s in subs:
                s.undeclare()
        finally:
            service.stop()
    msgs = [decode(b) for b in got.drain()]
    poses = [m for m in msgs if isinstance(m, Poses)]
    maps = [m for m in msgs if isinstance(m, Map)]
    assert service.rejected == 0
    assert len(poses) >= len(irs) // 2, (len(poses), service.dropped)
    assert maps and maps[-1].robot == info.src
    # poses are in the world frame, anchored at the robot's first pose
    first = poses[0].poses[info.src].pose
    assert np.allclose(first[:2], irs[0].pose[:2], atol=0.05)
    last = poses[-1].poses[info.src].pose
    assert np.hypot(last[0] - irs[-1].pose[0], last[1] - irs[-1].pose[1]) < 1.0
    # one pose per acquisition, in time order (a relocalisation's revisions are not re-sent)
    ts = [m.t for m in poses]
    assert ts == sorted(set(ts))
