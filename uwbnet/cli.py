"""The ``uwbnet`` command line (DESIGN.md, "Command line").

Every command has ``--help``; bad input gives one line on stderr and a non-zero exit, never a
traceback (``UWBNET_DEBUG=1`` shows it); no command leaves a half-written output file.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

EXIT_USAGE = 2
EXIT_ERROR = 1


class CliError(Exception):
    """A user-facing error: printed as one line, exit status 1."""


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (argparse prints the whole usage block by default)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"uwbnet: error: {message} (see '{self.prog} --help')\n")


def _positive(value: str) -> float:
    try:
        x = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {value!r}") from None
    if not (x > 0 and math.isfinite(x)):
        raise argparse.ArgumentTypeError(f"must be a positive number: {value!r}")
    return x


def _port(value: str) -> int:
    try:
        p = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {value!r}") from None
    if not 0 < p < 65536:
        raise argparse.ArgumentTypeError(f"port out of range: {p}")
    return p


def _out_path(path: str) -> Path:
    p = Path(path)
    if p.parent and not p.parent.exists():
        raise CliError(f"output directory does not exist: {p.parent}")
    return p


def _load_scenario(name: str) -> Any:
    from sim_nodes.scene import load_scenario

    return load_scenario(name)


# --- commands --------------------------------------------------------------------------------


def cmd_demo(args: argparse.Namespace) -> int:
    from rich.console import Console

    from uwbnet.demo import DemoConfig, run_demo

    if args.web is not None:
        raise CliError("--web: the live web view is not built yet (issue 7); use the terminal view")
    scenario = _load_scenario(args.scenario)
    record = str(_out_path(args.record)) if args.record else None
    console = Console()
    summary = run_demo(
        DemoConfig(
            scenario=scenario,
            duration=args.duration if args.duration is not None else math.inf,
            seed=args.seed,
            net=args.net,
            method=args.method,
            record=record,
        ),
        console,
    )
    print(json.dumps(summary))
    return 0


def cmd_sim(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from sim_nodes.record import simulate_to_mcap

    scenario = _load_scenario(args.scenario)
    out = _out_path(args.out)
    duration = args.duration if args.duration is not None else float(scenario.duration)
    with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("simulating", total=duration)
        n = simulate_to_mcap(
            scenario,
            out,
            duration=duration,
            seed=args.seed,
            net=args.net,
            progress=lambda dt: progress.advance(task, dt),
        )
    print(json.dumps({"out": str(out), "messages": n, "duration_s": duration, "seed": args.seed}))
    return 0


def _run_offline(
    args: argparse.Namespace, label: str, run: Callable[..., Any], **extra: Any
) -> int:
    """Run an offline pass ``run(src, out, method=..., progress=...)`` over a recording,
    with a progress bar on a terminal; print its counts (and ``extra``) as JSON."""
    from rich.progress import Progress

    src = Path(args.recording)
    if not src.is_file():
        raise CliError(f"no such recording: {src}")
    out = _out_path(args.out)
    size = src.stat().st_size
    with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task(label, total=size)
        stats = run(src, out, method=args.method, progress=lambda n: progress.advance(task, n))
    print(json.dumps({"out": str(out), **extra, **stats.as_dict()}))
    return 0


def cmd_track(args: argparse.Namespace) -> int:
    from fusion_center.offline import track_recording

    return _run_offline(args, "tracking", track_recording)


def cmd_ranging(args: argparse.Namespace) -> int:
    from node_agent.offline import range_recording

    return _run_offline(args, "ranging", range_recording, method=args.method)


def cmd_eval(args: argparse.Namespace) -> int:
    from fusion_center.offline import evaluate_files

    result = evaluate_files(args.truth, args.tracks, skip=args.skip, cutoff=args.cutoff)
    print(json.dumps(result))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from uwbnet.bench import BENCHES

    result = BENCHES[args.name](seed=args.seed)
    if not args.json:
        for k, v in result.items():
            print(f"{k:>28}: {v}")
    print(json.dumps(result))
    return 0


def _zenoh_overrides(args: argparse.Namespace) -> dict[tuple[str, ...], Any]:
    return {
        ("net",): args.net,
        ("zenoh", "connect"): args.connect,
        ("zenoh", "listen"): args.listen,
        ("zenoh", "mode"): args.mode,
    }


def cmd_node(args: argparse.Namespace) -> int:
    from uwbnet.config import NodeFile, load_config
    from uwbnet.processes import run_node, stop_on_signals

    cfg = load_config(NodeFile, args.config, _zenoh_overrides(args))
    with stop_on_signals() as stop:
        return run_node(cfg, stop)


def cmd_simnode(args: argparse.Namespace) -> int:
    from uwbnet.config import SimNodeFile, load_config
    from uwbnet.processes import run_simnode, stop_on_signals

    cfg = load_config(SimNodeFile, args.config, _zenoh_overrides(args))
    with stop_on_signals() as stop:
        return run_simnode(cfg, stop)


def cmd_fusion(args: argparse.Namespace) -> int:
    from uwbnet.config import FusionFile, load_config
    from uwbnet.processes import run_fusion, stop_on_signals

    overrides = _zenoh_overrides(args)
    overrides[("tracks_jsonl",)] = args.tracks_jsonl
    cfg = load_config(FusionFile, args.config, overrides)
    with stop_on_signals() as stop:
        return run_fusion(cfg, stop)


def cmd_record(args: argparse.Namespace) -> int:
    from uwbnet.config import RecordFile, load_config
    from uwbnet.processes import run_record, stop_on_signals

    cfg = load_config(RecordFile, args.config, _zenoh_overrides(args))
    out = _out_path(args.out)
    with stop_on_signals() as stop:
        result = run_record(cfg, out, stop, args.duration or math.inf)
    print(json.dumps(result))
    return 0


def cmd_objects(args: argparse.Namespace) -> int:
    from uwbnet.objects_cmd import ObjectsError, objects_report

    src = Path(args.recording)
    if not src.is_file():
        raise CliError(f"no such recording: {src}")
    try:
        report = objects_report(src)
    except ObjectsError as exc:
        raise CliError(str(exc)) from None
    if args.json:
        print(json.dumps(report))
    else:
        m = report["material"]
        print(
            f"class {report['class']}, {len(report['contour'])} contour points, "
            f"eps_r {m['permittivity']}, {m['surface']} surface"
        )
    return 0


def cmd_channel_table(args: argparse.Namespace) -> int:
    from sim_nodes.study import channel_study

    scenario = _load_scenario(args.scenario)
    try:
        rows = channel_study(scenario, args.seed, realizations=args.realizations)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if not args.json:
        print(
            f"{'model':<24}{'a':>6}{'N':>5}{'order':>6}{'power dB':>10}{'mean ns':>9}"
            f"{'rms DS ns':>10}{'AS deg':>8}{'paths/rx':>10}"
        )
        for r in rows:
            a = "-" if r["a"] is None else f"{r['a']:g}"
            print(
                f"{r['model']:<24}{a:>6}{r['N']:>5}{r['scatter_order']:>6}{r['power_db']:>10.2f}"
                f"{r['mean_delay_ns']:>9.2f}{r['rms_delay_spread_ns']:>10.2f}"
                f"{r['azimuth_spread_deg']:>8.1f}{r['paths_per_rx']:>10.0f}"
            )
    print(json.dumps({"scenario": scenario.name, "seed": args.seed, "rows": rows}))
    return 0


def cmd_channel_params(args: argparse.Namespace) -> int:
    from uwbnet.channel_cmd import link_figures

    _load_scenario(args.scenario)  # one-line error for a bad scenario before any work
    plot = _out_path(args.plot) if args.plot else None
    paths_csv = _out_path(args.paths) if args.paths else None
    try:
        result = link_figures(args.scenario, args.seed, args.stop, plot, paths_csv)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if not args.json:
        for label in ("ray_tracing", "hybrid"):
            print(f"{label}: " + ", ".join(f"{k} {v}" for k, v in result[label].items()))
    print(json.dumps(result))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from uwbnet.config import RecordFile, load_config
    from uwbnet.processes import run_replay, stop_on_signals

    src = Path(args.recording)
    if not src.is_file():
        raise CliError(f"no such recording: {src}")
    cfg = load_config(RecordFile, args.config, _zenoh_overrides(args))
    with stop_on_signals() as stop:
        result = run_replay(cfg, src, stop, args.rate)
    print(json.dumps(result))
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    from protocol.recording import recover_recording

    src = Path(args.partial)
    if not src.is_file():
        raise CliError(f"no such file: {src}")
    out = _out_path(args.out)
    count, damage = recover_recording(src, out)
    print(json.dumps({"out": str(out), "messages": count, "damage": damage}))
    return 0


def _rate(value: str) -> float:
    if value in ("inf", "max"):
        return math.inf
    return _positive(value)


def _add_zenoh_args(p: argparse.ArgumentParser, *, config_required: bool) -> None:
    p.add_argument(
        "--config", required=config_required, help="TOML configuration (deploy/examples/)"
    )
    p.add_argument("--net", help="network name (overrides the file and UWBNET_NET)")
    p.add_argument("--connect", action="append", help="zenoh endpoint to connect to (repeatable)")
    p.add_argument("--listen", action="append", help="zenoh endpoint to listen on (repeatable)")
    p.add_argument("--mode", choices=("peer", "client", "router"), help="zenoh mode")


def cmd_channel_dataset(args: argparse.Namespace) -> int:
    import time

    from uwbnet.channel_cmd import generate_dataset, write_dataset

    _load_scenario(args.scenario)
    out = _out_path(args.out)
    t0 = time.perf_counter()
    try:
        ds, cpu = generate_dataset(args.scenario, args.seed, args.workers, args.stops)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    wall = time.perf_counter() - t0
    write_dataset(ds, out)
    n_acq = int(ds.response.shape[0] * ds.response.shape[1])
    print(
        json.dumps(
            {
                "out": str(out),
                "acquisitions": n_acq,
                "receivers": 2,
                "frequencies": int(ds.frequencies.size),
                "wall_s": round(wall, 2),
                "cpu_s": round(cpu, 2),
                "workers": args.workers,
            }
        )
    )
    return 0


# --- parser ----------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="uwbnet", description="UWB radar sensor network runtime (CoLOR).")
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO level to stderr")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    d = sub.add_parser("demo", help="simulated network, node agents and fusion center, live")
    d.add_argument("--scenario", default="foyer3", help="shipped scenario name or TOML path")
    d.add_argument("--duration", type=_positive, help="seconds to run (default: until Ctrl-C)")
    d.add_argument("--seed", type=int, default=1, help="simulation seed")
    d.add_argument("--web", type=_port, help="serve the live web view on this port")
    d.add_argument("--record", help="also record the network to this MCAP file")
    d.add_argument("--net", default="demo", help="network name in the key expressions")
    d.add_argument(
        "--method",
        choices=("gmphd", "image"),
        default="gmphd",
        help="fusion method: labelled GM-PHD (9.2) or fused image (9.1)",
    )
    d.set_defaults(func=cmd_demo)

    s = sub.add_parser("sim", help="simulate a scenario into an MCAP recording")
    s.add_argument("scenario", help="shipped scenario name or TOML path")
    s.add_argument("--out", required=True, help="output MCAP file")
    s.add_argument("--duration", type=_positive, help="seconds (default: the scenario's)")
    s.add_argument("--seed", type=int, default=1, help="simulation seed")
    s.add_argument("--net", default="demo", help="network name in the topics")
    s.set_defaults(func=cmd_sim)

    t = sub.add_parser("track", help="node DSP and fusion over a recording, offline")
    t.add_argument("recording", help="input MCAP recording")
    t.add_argument("--out", required=True, help="output tracks JSONL")
    t.add_argument(
        "--method",
        choices=("gmphd", "image"),
        default="gmphd",
        help="fusion method: labelled GM-PHD (9.2) or fused image (9.1)",
    )
    t.set_defaults(func=cmd_track)

    r = sub.add_parser("ranging", help="first-path range and LOS/NLOS of every impulse response")
    r.add_argument("recording", help="input MCAP recording")
    r.add_argument("--out", required=True, help="output ranges JSONL")
    r.add_argument(
        "--method",
        choices=("mpd", "threshold", "adaptive", "peak"),
        default="adaptive",
        help="ToA estimator: maximum probability of detection (eq. 4-5), fixed or adaptive "
        "threshold, strongest peak",
    )
    r.set_defaults(func=cmd_ranging)

    e = sub.add_parser("eval", help="score tracks against a recording's truth")
    e.add_argument("--truth", required=True, help="MCAP recording with truth messages")
    e.add_argument("--tracks", required=True, help="tracks JSONL from 'uwbnet track'")
    e.add_argument("--skip", type=float, default=2.0, help="seconds at the start not scored")
    e.add_argument("--cutoff", type=_positive, default=1.0, help="OSPA/GOSPA cut-off c, m")
    e.set_defaults(func=cmd_eval)

    n = sub.add_parser("node", help="a node agent on a radar driver (field deployment)")
    _add_zenoh_args(n, config_required=True)
    n.set_defaults(func=cmd_node)

    sn = sub.add_parser("simnode", help="simulated nodes of a scenario with their node agents")
    _add_zenoh_args(sn, config_required=True)
    sn.set_defaults(func=cmd_simnode)

    f = sub.add_parser("fusion", help="the fusion center (and router) of a deployment")
    _add_zenoh_args(f, config_required=True)
    f.add_argument("--tracks-jsonl", help="also write every fusion update to this JSONL file")
    f.set_defaults(func=cmd_fusion)

    r = sub.add_parser("record", help="record the network to MCAP until SIGINT/SIGTERM")
    _add_zenoh_args(r, config_required=False)
    r.add_argument("--out", required=True, help="output MCAP file")
    r.add_argument("--duration", type=_positive, help="seconds to record (default: until stopped)")
    r.set_defaults(func=cmd_record)

    rp = sub.add_parser("replay", help="republish a recording's payloads unchanged")
    rp.add_argument("recording", help="input MCAP recording")
    _add_zenoh_args(rp, config_required=False)
    rp.add_argument(
        "--rate", type=_rate, default=1.0, help="speed-up over real time; 'inf' as fast as possible"
    )
    rp.set_defaults(func=cmd_replay)

    rc = sub.add_parser("recover", help="make a complete MCAP of a killed recorder's .partial")
    rc.add_argument("partial", help="the NAME.mcap.partial a killed recorder left")
    rc.add_argument("--out", required=True, help="output MCAP file")
    rc.set_defaults(func=cmd_recover)

    b = sub.add_parser("bench", help="benchmarks; JSON figures on the last line")
    b.add_argument("name", choices=("channel", "dsp", "fusion", "fuzz", "objects", "sim"))
    b.add_argument("--json", action="store_true", help="print only the JSON line")
    b.add_argument("--seed", type=int, default=0)
    b.set_defaults(func=cmd_bench)

    ob = sub.add_parser("objects", help="contour, material and class of a circular-scan recording")
    ob.add_argument("recording", help="MCAP of a [circle_scan] scenario (uwbnet sim)")
    ob.add_argument("--json", action="store_true", help="print the full report as JSON")
    ob.set_defaults(func=cmd_objects)

    c = sub.add_parser("channel", help="hybrid channel model: figures, plots, data sets")
    csub = c.add_subparsers(dest="channel_command", required=True, parser_class=_Parser)
    ct = csub.add_parser("table", help="ray tracing vs hybrid, a, N and scatter order (Fig. 12)")
    ct.add_argument("scenario", nargs="?", default="office", help="robot scenario (office)")
    ct.add_argument("--seed", type=int, default=0, help="realization seed")
    ct.add_argument("--realizations", type=int, default=3, help="realizations averaged per row")
    ct.add_argument("--json", action="store_true", help="print only the JSON line")
    ct.set_defaults(func=cmd_channel_table)
    cp = csub.add_parser("params", help="path loss, delays, spreads of one link; plots")
    cp.add_argument("scenario", help="shipped scenario name or TOML path")
    cp.add_argument("--stop", type=int, default=0, help="robot stop (or node number)")
    cp.add_argument("--seed", type=int, default=0, help="realization seed")
    cp.add_argument("--plot", help="save PDP and angular-PDP plots to this PNG file")
    cp.add_argument("--paths", help="save the hybrid path list (delays, amplitudes, angles) as CSV")
    cp.add_argument("--json", action="store_true", help="print only the JSON line")
    cp.set_defaults(func=cmd_channel_params)
    cd = csub.add_parser("dataset", help="frequency responses of a robot scenario (.npz)")
    cd.add_argument("scenario", help="robot scenario, e.g. room_pillar")
    cd.add_argument("--out", required=True, help="output .npz file")
    cd.add_argument("--seed", type=int, default=0, help="realization seed")
    cd.add_argument("--workers", type=int, default=2, choices=range(1, 65), metavar="N")
    cd.add_argument("--stops", type=int, help="only the first N stops")
    cd.set_defaults(func=cmd_channel_dataset)
    return p


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exception types that are the user's input, reported as one line."""
    from fusion_center.offline import TrackingError
    from node_agent.drivers.base import DriverError
    from node_agent.offline import RangingError
    from protocol import ProtocolError
    from sim_nodes.scene import ScenarioError
    from uwbnet.config import ConfigError

    return (
        CliError,
        ConfigError,
        ProtocolError,
        ScenarioError,
        TrackingError,
        RangingError,
        DriverError,
        OSError,
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("uwbnet: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if os.environ.get("UWBNET_DEBUG"):
            raise
        user = isinstance(exc, _user_errors())
        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        prefix = "error" if user else f"internal error ({type(exc).__name__})"
        print(f"uwbnet: {prefix}: {detail}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":
    sys.exit(main())
