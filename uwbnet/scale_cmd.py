"""``uwbnet scale``: N simulated nodes, M people, the fusion center, measured end to end.

Launches the processes of :mod:`uwbnet.scale_roles` (a hub: zenoh router, TDMA schedule and
fusion center or gateway; ``ceil(N / nodes_per_process)`` node processes; with ``workers`` > 1
one fusion worker per cell) on this machine, or spread over ``hosts`` network namespaces
joined to the hub's namespace by veth pairs (root only). After every node is scheduled and a
warm-up, it measures for ``duration`` s:

* end-to-end latency: arrival of a ``fusion/tracks`` message minus the acquisition time of
  each detection the update used (the ``t_acq`` field), p50 and p99;
* drops: acquisitions of the window (N per 20 ms TDMA frame) that never reached a track
  update, whatever lost them (a late slot, a full queue, the network, a late frame);
* throughput, and CPU (fraction of one core) and resident memory of every process;
* the tracking figures against the simulator's truth
  (:func:`fusion_center.tracking.metrics.evaluate`) and the people's cell-border crossings.

The run is real time when fewer than 0.1 % of acquisitions are lost and p99 latency stays
under one second (a fusion center that falls behind shows growing latency before drops).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

#: TDMA frame period of the generated buildings, s.
FRAME = 0.02
#: Time after every node is scheduled before the measurement starts, s.
WARMUP = 3.0


class ScaleError(RuntimeError):
    """A scale run cannot start or did not come up (one-line message)."""


#: Default radar window of a scale test, m of bistatic range. The simulator leaves people
#: beyond PEOPLE_RANGE (20 m) of a node out, so no person's echo lies beyond about
#: 2 x (20 + 0.8) m; 45 m keeps all of them and a margin, and cuts the noise drawn and the
#: samples the node DSP processes from 4,095 to 1,051 (issue 11, stop 22 notes: CPU per
#: acquisition all in 0.43 -> 0.34 ms at 64 nodes, eval figures unchanged).
IR_WINDOW = 45.0


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class ScaleConfig:
    """Parameters of ``uwbnet scale`` (see ``--help``)."""

    nodes: int
    people: int
    hosts: int = 1
    duration: float = 10.0
    workers: int = 1
    # 8 with the batch layout below (issue 11, stop 18 notes: 0.57-0.61 ms of CPU per
    # acquisition at 32 nodes against 0.73 with 4 per process). With a thread per agent, 8 per
    # process missed slots on the GIL (1.8 % drops at 12 nodes, none with 4 per process).
    nodes_per_process: int = 8
    # "batch" (default): one thread per node process serves the slots of its nodes that start
    # within 10 ms together, each at its own time, and publishes none before its slot starts
    # (node_agent.group, batch_window). Measured on the quiet machine (issue 11, stop 18
    # notes): 48 nodes 0.00-0.10 % drops against 0.31 % for "agent", 0.58 ms of CPU per
    # acquisition against 0.79-0.96. "agent": every agent has its own worker and publisher
    # threads; "process": the agents of a node process share one acquisition thread, in slot
    # order, one slot per wake-up (lost 2-14x more than "agent" at load 8-9, stop 17).
    threads: str = "batch"
    # a node process's nodes take every n_proc-th slot of the frame (False: adjacent slots)
    spread_slots: bool = False
    # SCHED_FIFO priority of every scale process (0: the normal scheduler); root only
    rt_priority: int = 0
    # the fusion center fuses frame f, complete or not, once a detection of frame f + frame_lag
    # arrives (FusionCoreConfig.frame_lag); the last node process of a frame then has only
    # about frame_lag - 1 frames of slack (issue 11, stop 19 notes)
    frame_lag: int = 2
    # an incomplete frame waits up to this many frames more for a node whose detection may
    # still be in flight (FusionCoreConfig.frame_wait); 0: off
    frame_wait: int = 0
    # --threads batch: a node process still serves a slot whose start passed less than this
    # (s) ago (SlotOrderGroup catch_up); 0: skipped, as before
    catch_up: float = 0.0
    # --threads batch: a node process's acquisition thread serves this many batches (frames)
    # per wake-up, each published at its own slots (SlotOrderGroup batches_per_wake)
    batches_per_wake: int = 1
    # the node DSP's longest range, m (NodeDspConfig.max_range): the CFAR, background and range
    # filter run on the window up to it instead of the whole 175 m impulse response; None:
    # the whole window. The simulator leaves people beyond 20 m out (PEOPLE_RANGE), so no echo
    # lies beyond about 2 x 21 m of bistatic range (issue 11, stop 22 notes)
    max_range: float | None = None
    # the simulated radar window, m of bistatic range: the node processes' simulator delivers
    # (and node_info declares) only the impulse-response samples up to it, with the thermal
    # noise drawn for those only (SimNetwork window); None: the whole 4,095-sample period
    # (175 m). Default: IR_WINDOW
    ir_window: float | None = IR_WINDOW
    # --threads batch: one thread per node process publishes frame f's messages at their
    # release and then computes frame f + 1, ahead (SlotOrderGroup pipeline = one frame): one
    # wake-up per frame instead of two (acquisition and publisher threads)
    pipeline: bool = False
    seed: int = 1
    net: str = "scale"
    out: str | None = None
    startup_timeout: float = 120.0


@dataclasses.dataclass(slots=True)
class _Proc:
    name: str
    role: str
    host: int
    popen: subprocess.Popen[str]
    lines: list[str] = dataclasses.field(default_factory=list)
    cpu0: float = 0.0

    def reader(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.append(line.strip())

    def saw(self, prefix: str) -> bool:
        return any(line.startswith(prefix) for line in self.lines)


def _proc_cpu(pid: int) -> float:
    """utime + stime of a process, s (Linux /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return math.nan
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _proc_rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


class NetnsHosts:
    """``count`` network namespaces: host 0 (the hub) linked to each other host by a veth pair;
    host ``i`` is 10.211.i.2, the hub is 10.211.i.1 towards it."""

    def __init__(self, count: int) -> None:
        tag = f"u11s{os.getpid() % 100000}"
        self.ns = [f"{tag}h{i}" for i in range(count)]
        self.veth = [f"{tag}v{i}" for i in range(count)]

    @staticmethod
    def why_not() -> str | None:
        """Why namespaces cannot be made here (None: they can)."""
        if os.geteuid() != 0:
            return "--hosts > 1 needs root (ip netns)"
        if shutil.which("ip") is None:
            return "--hosts > 1 needs iproute2 (ip)"
        return None

    def _sh(self, *cmd: str) -> None:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
        if r.returncode != 0:
            raise ScaleError(f"{' '.join(cmd)}: {r.stderr.strip()}")

    def create(self) -> None:
        for ns in self.ns:
            self._sh("ip", "netns", "add", ns)
            self._sh("ip", "-n", ns, "link", "set", "lo", "up")
        for i in range(1, len(self.ns)):
            far, near = self.veth[i], self.veth[i] + "f"
            self._sh("ip", "link", "add", far, "type", "veth", "peer", "name", near)
            self._sh("ip", "link", "set", far, "netns", self.ns[i])
            self._sh("ip", "link", "set", near, "netns", self.ns[0])
            self._sh("ip", "-n", self.ns[i], "addr", "add", f"10.211.{i}.2/24", "dev", far)
            self._sh("ip", "-n", self.ns[0], "addr", "add", f"10.211.{i}.1/24", "dev", near)
            self._sh("ip", "-n", self.ns[i], "link", "set", far, "up")
            self._sh("ip", "-n", self.ns[0], "link", "set", near, "up")

    def delete(self) -> None:
        for ns in self.ns:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)

    def prefix(self, host: int) -> list[str]:
        return ["ip", "netns", "exec", self.ns[host]]

    def hub_address(self, host: int, port: int) -> str:
        return f"tcp/127.0.0.1:{port}" if host == 0 else f"tcp/10.211.{host}.1:{port}"


def _plan(cfg: ScaleConfig) -> list[tuple[str, str, dict[str, Any]]]:
    """(name, role, role config) of every process but the hub; node ids and cell members."""
    from fusion_center.tracking.cells import nodes_of_cells
    from uwbnet.scale_roles import CELL_MARGIN, building, cells

    scenario = building(dataclasses.asdict(cfg) | {"workers": cfg.workers})
    ids = [n.id for n in scenario.nodes]
    plan = []
    per = max(1, cfg.nodes_per_process)
    n_proc = math.ceil(len(ids) / per)
    for g in range(n_proc):
        # The schedule gives the nodes slots in id order. Consecutive ids in one process put
        # its K acquisitions into K adjacent slots (20 ms / N apart), which one thread cannot
        # serve on time; every n_proc-th id spreads them over the frame (20 ms / K apart).
        group = ids[g::n_proc] if cfg.spread_slots else ids[g * per : (g + 1) * per]
        plan.append((f"nodes{g}", "nodes", {"ids": group, "threads": cfg.threads}))
    if cfg.workers > 1:
        xy = {n.id: n.pose[:2] for n in scenario.nodes}
        for k, ids_k in enumerate(nodes_of_cells(cells(dataclasses.asdict(cfg)), xy, CELL_MARGIN)):
            plan.append((f"worker{k}", "worker", {"cell": k, "ids": list(ids_k)}))
    return plan


def _spawn(
    name: str, role: str, host: int, role_cfg: dict[str, Any], prefix: list[str], log_dir: Path
) -> _Proc:
    env = dict(os.environ)
    # One process per core: OpenBLAS's own threads only fight the other processes for the two
    # cores (measured: a 120-path spectrum took 14 ms instead of 0.28 ms on a loaded machine).
    env.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    # -P (below) keeps the working directory off the children's sys.path; this process's own
    # source root goes first instead, so they run the same uwbnet, installed or not
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    err = open(log_dir / f"{name}.err", "w", encoding="utf-8")
    popen = subprocess.Popen(
        # -P: not the working directory first on sys.path (run from another checkout, the
        # processes imported that checkout's uwbnet, not this one's)
        [*prefix, sys.executable, "-P", "-m", "uwbnet.scale_roles", role, json.dumps(role_cfg)],
        stdout=subprocess.PIPE,
        stderr=err,
        text=True,
        env=env,
    )
    err.close()
    proc = _Proc(name=name, role=role, host=host, popen=popen)
    threading.Thread(target=proc.reader, name=f"read-{name}", daemon=True).start()
    return proc


def _wait_for(procs: list[_Proc], prefix: str, timeout: float, log_dir: Path) -> None:
    deadline = time.monotonic() + timeout
    while True:
        missing = [p for p in procs if not p.saw(prefix)]
        if not missing:
            return
        dead = [p for p in procs if p.popen.poll() is not None]
        if dead:
            tail = (log_dir / f"{dead[0].name}.err").read_text().strip().splitlines()[-1:]
            raise ScaleError(
                f"process {dead[0].name} exited early: {' '.join(tail) or 'no output'}"
            )
        if time.monotonic() > deadline:
            raise ScaleError(f"{missing[0].name} did not report '{prefix}' within {timeout:.0f} s")
        time.sleep(0.1)


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _stop_all(procs: list[_Proc], grace: float = 15.0) -> None:
    """SIGTERM every process, then SIGKILL what is left after ``grace`` s in all (a process
    still blocked opening its session, waiting for the router, cannot act on SIGTERM)."""
    for p in procs:
        if p.popen.poll() is None:
            p.popen.terminate()
    deadline = time.monotonic() + grace
    for p in procs:
        try:
            p.popen.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.popen.kill()
            p.popen.wait(5.0)


def run_scale(cfg: ScaleConfig) -> dict[str, Any]:
    """Run the scale test; the summary dict (``--json`` prints it on the last line)."""
    from protocol.transport import free_tcp_port

    if cfg.nodes < 1 or cfg.people < 0 or cfg.hosts < 1 or cfg.workers < 1:
        raise ScaleError("--nodes, --hosts and --workers must be >= 1, --people >= 0")
    if cfg.threads not in ("process", "agent", "batch"):
        raise ScaleError(f"--threads must be process, agent or batch, not {cfg.threads!r}")
    if not 0.0 <= cfg.catch_up <= 1.0:
        raise ScaleError(f"--catch-up must be 0 to 1 s, not {cfg.catch_up}")
    if cfg.catch_up and cfg.threads != "batch":
        raise ScaleError("--catch-up needs --threads batch")
    from node_agent.group import MAX_BATCHES_PER_WAKE

    if not (
        isinstance(cfg.batches_per_wake, int) and 1 <= cfg.batches_per_wake <= MAX_BATCHES_PER_WAKE
    ):
        raise ScaleError(
            f"--batches-per-wake must be an integer from 1 to {MAX_BATCHES_PER_WAKE},"
            f" not {cfg.batches_per_wake}"
        )
    if cfg.batches_per_wake > 1 and cfg.threads != "batch":
        raise ScaleError("--batches-per-wake needs --threads batch")
    if cfg.max_range is not None and not (math.isfinite(cfg.max_range) and cfg.max_range > 0):
        raise ScaleError(f"--max-range must be a positive number of metres, not {cfg.max_range}")
    if cfg.ir_window is not None and not (math.isfinite(cfg.ir_window) and cfg.ir_window > 0):
        raise ScaleError(f"--ir-window must be a positive number of metres, not {cfg.ir_window}")
    if cfg.pipeline and (cfg.threads != "batch" or cfg.batches_per_wake > 1):
        raise ScaleError("--pipeline needs --threads batch and --batches-per-wake 1")
    if cfg.frame_lag < 1:
        raise ScaleError(f"--frame-lag must be >= 1, not {cfg.frame_lag}")
    if cfg.frame_wait < 0:
        raise ScaleError(f"--frame-wait must be >= 0, not {cfg.frame_wait}")
    if not 0 <= cfg.rt_priority <= 99:
        raise ScaleError("--rt-priority must be 0 (off) to 99")
    if cfg.rt_priority and os.geteuid() != 0:
        raise ScaleError("--rt-priority needs root (SCHED_FIFO)")
    netns = None
    if cfg.hosts > 1:
        reason = NetnsHosts.why_not()
        if reason is not None:
            raise ScaleError(reason)
        netns = NetnsHosts(cfg.hosts)
    out_dir = Path(cfg.out) if cfg.out else Path(tempfile.mkdtemp(prefix="uwbnet-scale."))
    out_dir.mkdir(parents=True, exist_ok=True)
    # a reused --out must not lend this run an earlier run's output
    for stale in ("tracks.jsonl", "fusion_counters.json"):
        (out_dir / stale).unlink(missing_ok=True)
    port = free_tcp_port()
    base = {
        "net": cfg.net,
        "nodes": cfg.nodes,
        "people": cfg.people,
        "seed": cfg.seed,
        "workers": cfg.workers,
        "rt_priority": cfg.rt_priority,
        "frame_lag": cfg.frame_lag,
        "frame_wait": cfg.frame_wait,
        "catch_up": cfg.catch_up,
        "batches_per_wake": cfg.batches_per_wake,
        "max_range": cfg.max_range,
        "ir_window": cfg.ir_window,
        "pipeline": FRAME if cfg.pipeline else 0.0,
    }
    procs: list[_Proc] = []
    with contextlib.ExitStack() as stack:
        if threading.current_thread() is threading.main_thread():
            # SIGTERM (a ``timeout``, a CI runner) stops the run like Ctrl-C: the exit stack
            # stops the processes and deletes the namespaces.
            previous = signal.signal(signal.SIGTERM, _interrupt)
            stack.callback(signal.signal, signal.SIGTERM, previous)
        if netns is not None:
            stack.callback(netns.delete)
            netns.create()
        # LIFO: the processes stop before the namespaces go.
        stack.callback(_stop_all, procs)

        def prefix(host: int) -> list[str]:
            return netns.prefix(host) if netns is not None else []

        def address(host: int) -> str:
            return netns.hub_address(host, port) if netns else f"tcp/127.0.0.1:{port}"

        # The nodes and workers start first (importing, building the scene, waiting for the
        # router); the hub last: it sets the TDMA epoch (scenario time 0) once it is up.
        for i, (name, role, extra) in enumerate(_plan(cfg)):
            # Hosts in turn; the hub's host only when there is no other.
            host = 0 if cfg.hosts == 1 else 1 + i % (cfg.hosts - 1)
            rc = base | extra | {"connect": address(host)}
            procs.append(_spawn(name, role, host, rc, prefix(host), out_dir))
        _wait_for(procs, "started", cfg.startup_timeout, out_dir)
        hub_cfg = base | {
            "listen": f"tcp/0.0.0.0:{port}" if netns else f"tcp/127.0.0.1:{port}",
            "out": str(out_dir),
        }
        hub = _spawn("hub", "hub", 0, hub_cfg, prefix(0), out_dir)
        procs.append(hub)
        _wait_for(procs, "ready", cfg.startup_timeout, out_dir)
        epoch = float(next(x for x in hub.lines if x.startswith("ready")).split()[-1])
        _wait_for([hub], "scheduled", cfg.startup_timeout, out_dir)
        time.sleep(WARMUP)
        # The window: whole TDMA frames.
        w0 = epoch + math.ceil((time.time() - epoch) / FRAME) * FRAME
        time.sleep(max(0.0, w0 - time.time()))
        cpu0 = {p.name: _proc_cpu(p.popen.pid) for p in procs}
        time.sleep(cfg.duration)
        w1 = w0 + round(cfg.duration / FRAME) * FRAME
        cpu1 = {p.name: _proc_cpu(p.popen.pid) for p in procs}
        rss = {p.name: _proc_rss_mb(p.popen.pid) for p in procs}
        wall = time.time() - w0
        load = os.getloadavg()
        time.sleep(0.5)  # the last updates of the window arrive
    # The exit stack stopped everything: the hub wrote its tracks on the way out.
    tracks_path = out_dir / "tracks.jsonl"
    if not tracks_path.exists():
        raise ScaleError(f"the hub wrote no {tracks_path} (see {out_dir}/hub.err)")
    processes = [
        {
            "name": p.name,
            "role": p.role,
            "host": p.host,
            "cpu": round((cpu1[p.name] - cpu0[p.name]) / wall, 3),
            "rss_mb": round(rss[p.name], 1),
        }
        for p in procs
    ]
    summary = analyse(cfg, tracks_path, epoch, w0, w1)
    summary.update(
        hosts=cfg.hosts,
        workers=cfg.workers,
        duration_s=round(w1 - w0, 3),
        load_avg=[round(x, 2) for x in load],
        cores=os.cpu_count(),
        cpu_total=round(sum(p["cpu"] for p in processes), 3),
        processes=processes,
        out=str(out_dir),
    )
    summary["realtime"] = bool(
        summary["drop_rate"] < 1e-3
        and summary["p99_latency_ms"] is not None
        and summary["p99_latency_ms"] < 1000.0
    )
    return summary


def analyse(
    cfg: ScaleConfig, tracks_path: Path, epoch: float, w0: float, w1: float
) -> dict[str, Any]:
    """Latency, drops, throughput and tracking figures of a run's ``tracks.jsonl``."""
    from fusion_center.offline import read_tracks
    from fusion_center.tracking.cells import border_crossings
    from fusion_center.tracking.metrics import evaluate
    from sim_nodes.network import SimNetwork
    from uwbnet.scale_roles import building, cells

    base = dataclasses.asdict(cfg)
    lat: list[np.ndarray] = []
    acquired: set[float] = set()
    updates = 0
    with open(tracks_path, encoding="utf-8") as f:
        for line in f:
            rec = json.loads(line)
            t_acq = np.asarray(rec["t_acq"], dtype=np.float64)
            t_acq = t_acq[(t_acq >= w0) & (t_acq < w1)]
            if t_acq.size:
                updates += 1
                lat.append(rec["recv"] - t_acq)
                acquired.update(t_acq.tolist())
    expected = cfg.nodes * round((w1 - w0) / FRAME)
    lat_ms = np.concatenate(lat) * 1e3 if lat else np.zeros(0)
    tracks = [(t, ids, xy) for t, ids, xy in read_tracks(tracks_path) if w0 <= t < w1]
    network = SimNetwork(building(base), cfg.seed)
    truth = []
    for t in np.arange(w0 - 1.0, w1 + 1.0, FRAME):
        people = network.truth(float(t) - epoch)
        ids = np.array([p["id"] for p in people], dtype=np.int64)
        xy = np.array([(p["x"], p["y"]) for p in people], dtype=np.float64).reshape(-1, 2)
        truth.append((float(t), ids, xy))
    figures = evaluate(truth, tracks, c=1.0) if tracks else {}
    strips = cells(base | {"workers": max(cfg.workers, 1)})
    crossings = border_crossings(strips, [s for s in truth if w0 <= s[0] < w1])
    switches = figures.get("id_switches")
    counters_path = tracks_path.with_name("fusion_counters.json")
    counters = json.loads(counters_path.read_text()) if counters_path.exists() else {}
    return {
        "nodes": cfg.nodes,
        "people": cfg.people,
        # the options that change the CPU per acquisition, so that runs can be told apart
        "ir_window": cfg.ir_window,
        "max_range": cfg.max_range,
        "batches_per_wake": cfg.batches_per_wake,
        "pipeline": cfg.pipeline,
        "p50_latency_ms": round(float(np.percentile(lat_ms, 50)), 2) if lat_ms.size else None,
        "p99_latency_ms": round(float(np.percentile(lat_ms, 99)), 2) if lat_ms.size else None,
        "max_latency_ms": round(float(lat_ms.max()), 2) if lat_ms.size else None,
        "drop_rate": round(1.0 - len(acquired) / expected, 5) if expected else 0.0,
        "acquisitions_expected": expected,
        "acquisitions_fused": len(acquired),
        # the whole run's: detections that arrived after the fusion center fused their frame
        # (the hub's; with several workers the cells assemble the frames and this is None)
        "late_detections": counters.get("late") if cfg.workers <= 1 else None,
        "detections_per_s": round(len(acquired) / (w1 - w0), 1),
        "track_updates_per_s": round(updates / (w1 - w0), 1),
        "ospa_mean": _round(figures.get("ospa_p2_mean")),
        "gospa_mean": _round(figures.get("gospa_p2_mean")),
        "card_correct_fraction": _round(figures.get("card_correct_fraction")),
        "id_switches": switches,
        "border_crossings": crossings,
        "id_switches_per_100_crossings": (
            round(100.0 * switches / crossings, 2) if crossings and switches is not None else None
        ),
    }


def _round(x: Any) -> Any:
    return round(float(x), 4) if isinstance(x, float | int) else x


def summary_text(summary: dict[str, Any]) -> str:
    """A readable summary of a run (printed before the JSON line)."""
    s = summary
    lines = [
        f"uwbnet scale: {s['nodes']} nodes, {s['people']} people, {s['workers']} fusion "
        f"worker(s), {s['hosts']} host(s), {s['duration_s']} s measured "
        f"(load {s['load_avg'][0]} on {s['cores']} cores)",
        f"  real time: {'yes' if s['realtime'] else 'NO'}  drops {100 * s['drop_rate']:.3f} %  "
        f"latency p50 {s['p50_latency_ms']} ms  p99 {s['p99_latency_ms']} ms",
        f"  detections/s {s['detections_per_s']}  track updates/s {s['track_updates_per_s']}  "
        f"OSPA {s['ospa_mean']} m  ID switches {s['id_switches']} "
        f"({s['border_crossings']} border crossings)",
    ]
    lines += [
        f"  {p['name']:>10} host {p['host']}  cpu {100 * p['cpu']:5.1f} %  {p['rss_mb']} MB"
        for p in s["processes"]
    ]
    lines.append(f"  files: {s['out']}")
    return "\n".join(lines)
