"""The serial radar driver against a radar emulated on a real pseudo-terminal (no mocks)."""

from __future__ import annotations

import contextlib
import time

import numpy as np
import pytest
import zenoh

from fusion_center.service import FusionConfig, FusionService
from node_agent.agent import AgentConfig, NodeAgent
from node_agent.drivers import DriverError, get_driver_class
from node_agent.drivers.serial import SerialDriver
from node_agent.drivers.serial_emulator import PtyRadarEmulator
from node_agent.drivers.serial_frames import DeviceInfo
from node_agent.tdma import SlotTiming
from protocol.transport import session_config

pytestmark = pytest.mark.faults

INFO = DeviceInfo(fs=7e9, t0=0.0, f_low=0.0, f_high=3.5e9, rate=50.0, n=4095, n_rx=2)


def _slot(i: int) -> SlotTiming:
    return SlotTiming(frame=i, slot=0, tx="s/tx", t=100.0 + 0.02 * i, duration=0.02)


@pytest.fixture
def emulator(tmp_path):  # type: ignore[no-untyped-def]
    with PtyRadarEmulator(INFO, link=tmp_path / "ttyRADAR", seed=5) as emu:
        yield emu


def test_driver_is_registered_and_describes_the_device(emulator):
    assert get_driver_class("serial") is SerialDriver
    with SerialDriver(emulator.port, node="s", pose=(1.0, 2.0, 1.0, 0.5)) as drv:
        d = drv.describe()
        assert d["radar"].n == 4095 and d["radar"].fs == 7e9 and d["pose"] == (1.0, 2.0, 1.0, 0.5)
        acq = drv.acquire(_slot(0))
        assert acq.h.shape == (2, 4095) and acq.h.dtype == np.float32
        assert acq.tx == "s/tx" and acq.rx == ("rx1", "rx2") and acq.t == _slot(0).t
        assert np.argmax(acq.h[0]) == 4095 // 4


def test_garbage_and_corrupt_frames_cost_only_their_acquisitions(emulator):
    with SerialDriver(emulator.port, node="s", timeout=0.2) as drv:
        emulator.garbage = 37
        emulator.corrupt_every = 3
        ok = failed = 0
        for i in range(12):
            try:
                drv.acquire(_slot(i))
                ok += 1
            except DriverError as exc:
                assert "no IR within" in str(exc)
                failed += 1
        assert failed == 4 and ok == 8
        assert drv.parser.crc_errors >= 4 and drv.parser.garbage_bytes >= 12 * 37


def test_silent_device_times_out_and_late_answers_are_discarded(emulator):
    with SerialDriver(emulator.port, node="s", timeout=0.15) as drv:
        emulator.delay = 0.25  # answers arrive after the driver gave up
        t0 = time.monotonic()
        with pytest.raises(DriverError, match=r"no IR within 0\.15 s"):
            drv.acquire(_slot(0))
        assert time.monotonic() - t0 < 0.5
        emulator.delay = 0.0
        # The late IR of trigger 0 arrives now; the driver must not take it for trigger 1.
        time.sleep(0.3)
        drv.acquire(_slot(1))
        assert drv.stale >= 1


def test_unplug_fails_fast_and_replug_resumes_without_restart(emulator):
    with SerialDriver(emulator.port, node="s", timeout=0.2, reopen_period=0.1) as drv:
        drv.acquire(_slot(0))
        emulator.unplug()
        with pytest.raises(DriverError, match="device gone"):
            for i in range(1, 5):  # the first read after the hang-up may still see buffered data
                drv.acquire(_slot(i))
        emulator.replug()
        deadline = time.monotonic() + 5.0
        while True:
            try:
                drv.acquire(_slot(10))
                break
            except DriverError:
                assert time.monotonic() < deadline, "driver did not resume after replug"
                time.sleep(0.05)
        assert drv.reopened >= 1


def test_missing_device_is_a_one_line_driver_error(tmp_path):
    with pytest.raises(DriverError, match="cannot open"):
        SerialDriver(str(tmp_path / "nothing"))


def test_node_agent_on_serial_driver_joins_the_fusion_center(emulator, hub_endpoint):
    with contextlib.ExitStack() as stack:
        fs = stack.enter_context(zenoh.open(session_config(listen=[hub_endpoint])))
        fusion = FusionService(fs, FusionConfig(net="ser"))
        fusion.start()
        stack.callback(fusion.stop)
        ns = stack.enter_context(zenoh.open(session_config(connect=[hub_endpoint])))
        drv = stack.enter_context(SerialDriver(emulator.port, node="s1", pose=(0, 0, 1, 0)))
        agent = NodeAgent(ns, drv, AgentConfig(node="s1", net="ser", publish_ir=False))
        agent.start()
        stack.callback(agent.stop)
        deadline = time.monotonic() + 10.0
        while fusion.health.get("s1") is None or fusion.health["s1"].detections < 20:
            assert time.monotonic() < deadline, "no detections from the serial node"
            time.sleep(0.05)
        assert "s1" in fusion.core.nodes
        assert agent.counters["driver_errors"] == 0


def test_uwbnet_node_process_runs_the_serial_driver_from_its_toml(
    emulator, hub_endpoint, procs, tmp_path
):
    cfg = tmp_path / "node.toml"
    cfg.write_text(
        'net = "ser"\nnode = "s9"\npublish_ir = false\n[describe]\npose = [1.0, 2.0, 1.0, 0.0]\n'
        f'[driver]\nname = "serial"\n[driver.options]\nport = "{emulator.port}"\ntimeout = 0.3\n'
        f'[zenoh]\nmode = "client"\nconnect = ["{hub_endpoint}"]\n'
    )
    with zenoh.open(session_config(mode="router", listen=[hub_endpoint])) as fs:
        fusion = FusionService(fs, FusionConfig(net="ser"))
        fusion.start()
        try:
            node = procs.uwbnet("-v", "node", "--config", str(cfg), name="node")
            deadline = time.monotonic() + 20.0
            while fusion.health.get("s9") is None or fusion.health["s9"].detections < 20:
                assert node.poll() is None, procs.log("node")
                assert time.monotonic() < deadline, procs.log("node")
                time.sleep(0.05)
            assert fusion.core.nodes["s9"].pose == (1.0, 2.0, 1.0, 0.0)
            assert procs.stop(node) == 0
            assert "Traceback" not in procs.log("node")
        finally:
            fusion.stop()
