"""Three hosts as network namespaces joined by veth pairs, with mutual TLS.

``fusion`` (the fusion center, the zenoh router, and a recorder) is linked to ``hostA`` and
``hostB``, each running ``uwbnet simnode`` with three foyer3 sensors as a TLS client. The test
cuts hostA's link for 5 s, SIGKILLs hostB's process and restarts it, and checks from the
recording and the fusion center's log that the network notices, keeps tracking and recovers.

Needs root (``ip netns``) and openssl; skipped with the reason printed otherwise. Namespaces
are deleted in the fixture's finalizer, after every process in them was killed.
"""

from __future__ import annotations

import datetime as dt
import itertools
import json
import os
import re
import shutil
import subprocess
import threading
import time
from collections import defaultdict
from pathlib import Path

import pytest

from fusion_center.offline import evaluate_files
from protocol import Detections
from protocol.recording import read_recording

pytestmark = [pytest.mark.integration, pytest.mark.multihost, pytest.mark.faults, pytest.mark.slow]

NET = "mhost"
MAKE_CERTS = Path(__file__).parents[2] / "deploy" / "make-certs.sh"
CUT = 5.0
#: Seconds after the restart that the recovered tracks are scored over. 5 s gave a correct
#: count of 0.78-1.0 between runs of the same code (4 runs; one CI run failed the 0.8 bound
#: at 0.776); 10 s gave 0.99-1.0 in 4 runs.
SCORED = 10.0


def _run(*cmd: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=30)


def _why_no_netns() -> str | None:
    if os.geteuid() != 0:
        return "multi-host tests need root for ip netns"
    if shutil.which("ip") is None or shutil.which("openssl") is None:
        return "multi-host tests need iproute2 (ip) and openssl"
    probe = f"u6probe{os.getpid()}"
    r = _run("ip", "netns", "add", probe)
    if r.returncode != 0:
        return f"ip netns add failed: {r.stderr.strip()}"
    _run("ip", "netns", "del", probe)
    return None


class Hosts:
    """Namespaces ``fusion``, ``hostA``, ``hostB``; fusion is 10.66.1.1 towards A (10.66.1.2)
    and 10.66.2.1 towards B (10.66.2.2)."""

    def __init__(self) -> None:
        tag = f"u6{os.getpid() % 100000}"
        self.ns = {h: f"{tag}{h}" for h in ("fusion", "hostA", "hostB")}
        self.link = {"hostA": f"{tag}a", "hostB": f"{tag}b"}  # the host side of each veth
        self.fusion_ip = {"hostA": "10.66.1.1", "hostB": "10.66.2.1"}

    def sh(self, *cmd: str) -> None:
        r = _run(*cmd)
        if r.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)}: {r.stderr.strip()}")

    def exec_prefix(self, host: str) -> list[str]:
        return ["ip", "netns", "exec", self.ns[host]]

    def create(self) -> None:
        for ns in self.ns.values():
            self.sh("ip", "netns", "add", ns)
            self.sh("ip", "-n", ns, "link", "set", "lo", "up")
        for i, host in enumerate(("hostA", "hostB"), start=1):
            far, near = self.link[host], self.link[host] + "f"
            self.sh("ip", "link", "add", far, "type", "veth", "peer", "name", near)
            self.sh("ip", "link", "set", far, "netns", self.ns[host])
            self.sh("ip", "link", "set", near, "netns", self.ns["fusion"])
            self.sh("ip", "-n", self.ns[host], "addr", "add", f"10.66.{i}.2/24", "dev", far)
            self.sh("ip", "-n", self.ns["fusion"], "addr", "add", f"10.66.{i}.1/24", "dev", near)
            self.sh("ip", "-n", self.ns[host], "link", "set", far, "up")
            self.sh("ip", "-n", self.ns["fusion"], "link", "set", near, "up")

    def set_link(self, host: str, up: bool) -> None:
        state = "up" if up else "down"
        self.sh("ip", "-n", self.ns[host], "link", "set", self.link[host], state)

    def delete(self) -> None:
        for ns in self.ns.values():
            _run("ip", "netns", "del", ns)


@pytest.fixture
def hosts(procs):  # type: ignore[no-untyped-def]
    reason = _why_no_netns()
    if reason is not None:
        print(f"\nSKIP multihost: {reason}")
        pytest.skip(reason)
    h = Hosts()
    try:
        h.create()
        yield h
    finally:
        procs.kill_all()  # processes first: a namespace lives on while a process uses it
        h.delete()


def _log_times(text: str, pattern: str) -> list[float]:
    """Epoch times of the log lines matching ``pattern`` (logging's default asctime)."""
    out = []
    for line in text.splitlines():
        if re.search(pattern, line):
            stamp = dt.datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f")
            out.append(stamp.timestamp())
    return out


def _wait_log(procs, name: str, pattern: str, timeout: float, after: float = 0.0) -> float:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while True:
        times = [t for t in _log_times(procs.log(name), pattern) if t >= after]
        if times:
            return times[0]
        if time.monotonic() > deadline:
            tail = "\n".join(procs.log(name).splitlines()[-15:])
            raise AssertionError(f"{name}: no /{pattern}/ within {timeout} s; log tail:\n{tail}")
        threading.Event().wait(0.05)


def _configs(tmp: Path, certs: Path, hosts: Hosts) -> dict[str, Path]:
    def tls(name: str) -> str:
        return (
            f'[zenoh.tls]\nca = "{certs}/ca.pem"\ncert = "{certs}/{name}.pem"\n'
            f'key = "{certs}/{name}.key"\n'
        )

    files = {
        "fusion": f'net = "{NET}"\ntracks_jsonl = "{tmp}/live.jsonl"\n'
        '[zenoh]\nmode = "router"\nlisten = ["tls/0.0.0.0:7447"]\nlease = "750 ms"\n'
        + tls("fusion")
        + '[zenoh.access]\nmembers = ["fusion", "hostA", "hostB", "recorder"]\n',
        "recorder": f'net = "{NET}"\n[zenoh]\nmode = "client"\n'
        'connect = ["tls/127.0.0.1:7447"]\nlease = "750 ms"\n' + tls("recorder"),
    }
    for host, nodes, truth in (
        ("hostA", "bat1 bat2 bat3", "true"),
        ("hostB", "bat4 bat5 bat6", "false"),
    ):
        files[host] = (
            f'net = "{NET}"\nscenario = "foyer3"\nseed = 1\nnodes = {json.dumps(nodes.split())}\n'
            f'truth = {truth}\n[zenoh]\nmode = "client"\n'
            f'connect = ["tls/{hosts.fusion_ip[host]}:7447"]\nlease = "750 ms"\n' + tls(host)
        )
    paths = {}
    for name, text in files.items():
        paths[name] = tmp / f"{name}.toml"
        paths[name].write_text(text)
    return paths


def test_three_hosts_with_tls_survive_a_link_cut_and_a_killed_node_process(hosts, procs, tmp_path):
    certs = tmp_path / "certs"
    subprocess.run(
        [str(MAKE_CERTS), str(certs), "fusion", "hostA", "hostB", "recorder"],
        check=True,
        capture_output=True,
    )
    cfg = _configs(tmp_path, certs, hosts)
    rec_path = tmp_path / "net.mcap"

    def start(host: str, name: str, *args: str):  # type: ignore[no-untyped-def]
        return procs.uwbnet("-v", *args, name=name, prefix=hosts.exec_prefix(host))

    fusion = start("fusion", "fusion", "fusion", "--config", str(cfg["fusion"]))
    rec = start("fusion", "rec", "record", "--config", str(cfg["recorder"]), "--out", str(rec_path))
    _wait_log(procs, "rec", "recording network", 30.0)
    sim_a = start("hostA", "simA", "simnode", "--config", str(cfg["hostA"]))
    sim_b = start("hostB", "simB", "simnode", "--config", str(cfg["hostB"]))
    _wait_log(procs, "fusion", "TDMA schedule: 6 slots", 40.0)
    threading.Event().wait(4.0)

    # 1. Cut hostA's link for 5 s.
    cut_at = time.time()
    hosts.set_link("hostA", up=False)
    threading.Event().wait(CUT)
    hosts.set_link("hostA", up=True)
    up_at = time.time()
    cut_noticed = _wait_log(procs, "fusion", "node bat1 lost", 5.0, after=cut_at)
    back = _wait_log(procs, "fusion", "node bat1 joined", 20.0, after=up_at - 0.1)
    threading.Event().wait(3.0)

    # 2. SIGKILL hostB's process, then restart it.
    sim_b.kill()
    killed_at = time.time()
    sim_b.wait(10)
    kill_noticed = _wait_log(procs, "fusion", "node bat4 lost", 5.0, after=killed_at)
    threading.Event().wait(2.0)
    restarted_at = time.time()
    sim_b = start("hostB", "simB2", "simnode", "--config", str(cfg["hostB"]))
    readmitted = _wait_log(procs, "fusion", "node bat4 joined", 30.0, after=restarted_at)
    # the restarted nodes deliver and tracks settle (1 s), then SCORED seconds are scored
    threading.Event().wait(1.0 + SCORED)
    end_at = time.time()

    for p in (sim_a, sim_b, rec, fusion):
        assert procs.stop(p) == 0
    logs = "".join(procs.log(n) for n in ("fusion", "rec", "simA", "simB", "simB2"))
    assert "Traceback" not in logs

    # Detections lost: gaps in each node's seq, split into inside and outside the cut.
    seqs: dict[str, list[tuple[int, float]]] = defaultdict(list)
    for m in read_recording(rec_path):
        if m.kind == "detections":
            d = Detections.from_wire(m.payload)
            seqs[d.src].append((d.seq, d.t))
    lost_in_cut = lost_outside = 0
    for src, items in seqs.items():
        items.sort(key=lambda x: x[1])  # by time: a restarted process begins again at seq 0
        for (s0, t0), (s1, t1) in itertools.pairwise(items):
            if s1 <= s0:
                continue
            gap = s1 - s0 - 1
            if gap and src in ("bat1", "bat2", "bat3") and t0 >= cut_at - 1.5 and t1 <= back + 2:
                lost_in_cut += gap
            else:
                lost_outside += gap
    assert lost_outside == 0, f"{lost_outside} detections lost outside the link cut"

    # Tracks recover: the last seconds, after the restart, score like a healthy network.
    result = evaluate_files(
        rec_path, tmp_path / "live.jsonl", skip=end_at - SCORED - _first_truth(rec_path)
    )
    figures = {
        "cut_noticed_s": round(cut_noticed - cut_at, 3),
        "cut_readmitted_after_link_up_s": round(back - up_at, 3),
        "kill_noticed_s": round(kill_noticed - killed_at, 3),
        "readmitted_after_restart_s": round(readmitted - restarted_at, 3),
        "detections_lost_in_cut": lost_in_cut,
        "detections_lost_outside_cut": lost_outside,
        "final_ospa_p2": round(result["ospa_p2_mean"], 3),
        "final_card_correct": round(result["card_correct_fraction"], 3),
    }
    print("\nmultihost figures: " + json.dumps(figures))
    assert kill_noticed - killed_at < 1.0
    # Lease 750 ms (measured 0.75 s to notice); slack for a loaded CI machine.
    assert cut_noticed - cut_at < 1.25
    assert result["card_correct_fraction"] > 0.8 and result["ospa_p2_mean"] < 0.4


def _first_truth(path: Path) -> float:
    return next(m.t for m in read_recording(path) if m.kind == "truth")
