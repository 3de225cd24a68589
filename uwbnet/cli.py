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


def _ir_window(value: str) -> float | None:
    """``uwbnet scale --ir-window``: a positive number of metres, or ``full`` (None)."""
    return None if value.strip().lower() == "full" else _positive(value)


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


# The live runtime (demo, simnode, fusion) runs numpy with one BLAS thread per process, set
# before numpy loads: on a shared machine OpenBLAS's thread pool only spins against the other
# processes (the simulator's small matrix products took 50x longer; docs/capacity.md).


def cmd_demo(args: argparse.Namespace) -> int:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see above cmd_demo
    from rich.console import Console

    from uwbnet.demo import DemoConfig, run_demo

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
            web=args.web,
            web_host=args.web_host,
            image_rate=args.image_rate,
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
    if not scenario.nodes and scenario.robot is not None:
        return _sim_robot(args, scenario, out)
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


def _sim_robot(args: argparse.Namespace, scenario: Any, out: Path) -> int:
    """``uwbnet sim`` of a ``[robot]`` scenario: every stop and heading (sim_nodes.robot_record)."""
    from rich.progress import Progress

    from uwbnet.robot_sim_cmd import simulate_robot

    if args.stops is not None and args.stops < 1:
        raise CliError(f"--stops must be at least 1, got {args.stops}")
    if args.duration is not None:
        raise CliError("--duration does not apply to a [robot] scenario (use --stops)")
    with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("channel (robot stops)", total=None)

        def report(stage: str, done: int, total: int) -> None:
            progress.update(task, description=stage, completed=done, total=total)

        result = simulate_robot(
            args.scenario,
            scenario,
            out,
            seed=args.seed,
            workers=args.workers,
            stops=args.stops,
            snr_db=args.snr,
            net=args.net,
            progress=report,
        )
    print(json.dumps(result))
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


def cmd_localize(args: argparse.Namespace) -> int:
    from uwbnet.localization_cmd import localization_table, localize, table_lines

    src = Path(args.recording)
    if not src.is_file():
        raise CliError(f"no such recording: {src}")
    if args.table:
        for line in table_lines(localization_table(src)):
            print(line)
        return 0
    if not args.out:
        raise CliError("give --out POSES.jsonl (or --table)")
    out = _out_path(args.out)
    print(json.dumps(localize(src, out, method=args.method, mitigate=not args.no_mitigation)))
    return 0


def cmd_image(args: argparse.Namespace) -> int:
    import time

    import numpy as np
    from rich.progress import Progress

    from uwbnet.image_cmd import (
        ImageOptions,
        default_grid,
        make_image,
        read_observations,
        scenario_figures,
        write_npz,
        write_png,
    )

    src = Path(args.recording)
    if not src.is_file():
        raise CliError(f"no such recording: {src}")
    out = _out_path(args.out)
    png = _out_path(args.png) if args.png else None
    scenario = _load_scenario(args.scenario) if args.scenario else None
    opts = ImageOptions(
        method=args.method,
        nx=args.nx,
        ny=args.ny,
        bounds=tuple(args.bounds) if args.bounds else None,
        margin=args.margin,
        z=args.z,
        envelope=not args.raw,
        coherent=args.coherent,
        pattern=args.pattern,
        gate=args.gate,
        workers=args.workers,
    )
    t0 = time.perf_counter()
    with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("reading", total=src.stat().st_size)
        obs, rejected = read_observations(src, lambda n: progress.advance(task, n))
        grid = default_grid(obs, opts)
        progress.update(
            task, description=f"imaging ({args.method})", completed=0, total=grid.nx * grid.ny
        )
        t1 = time.perf_counter()
        img = make_image(obs, grid, opts, lambda n: progress.advance(task, n))
    t2 = time.perf_counter()
    write_npz(out, img, grid, args.method)
    result: dict[str, Any] = {
        "out": str(out),
        "method": args.method,
        "observations": len(obs),
        "rejected": rejected,
        "nx": grid.nx,
        "ny": grid.ny,
        "read_s": round(t1 - t0, 2),
        "image_s": round(t2 - t1, 2),
    }
    if scenario is not None:
        result.update(scenario_figures(img, grid, scenario))
    if png is not None:
        outlines = []
        if scenario is not None:
            outlines = [o.footprint for o in scenario.objects]
            outlines += [scenario.room.outline] if scenario.room is not None else []
            outlines += [[w.start, w.end] for w in scenario.walls]
        write_png(
            png,
            img,
            grid,
            f"{args.method}: {src.name}",
            db_range=args.db_range,
            outlines=outlines,
            positions=np.unique(obs.tx[:, :2].round(3), axis=0),
        )
        result["png"] = str(png)
    print(json.dumps(result))
    return 0


def cmd_stationary(args: argparse.Namespace) -> int:
    import dataclasses

    from fusion_center.imaging.stationary import detection_table

    rows = detection_table(args.sinr, pf=args.pf, trials=args.trials, seed=args.seed)
    table = [dataclasses.asdict(r) for r in rows]
    if not args.json:
        print(
            f"{'SINR dB':>8}{'out dB':>8}{'Pd theory':>10}{'Pd sim':>8}{'Pf sim':>8}{'Pd emp':>8}"
        )
        for r in rows:
            print(
                f"{r.sinr_db:>8.1f}{r.output_sinr_db:>8.2f}{r.pd_theory:>10.4f}"
                f"{r.pd_simulated:>8.4f}{r.pf_simulated:>8.4f}{r.pd_empirical_threshold:>8.4f}"
            )
    print(json.dumps({"pf": args.pf, "trials": args.trials, "seed": args.seed, "rows": table}))
    return 0


def cmd_map(args: argparse.Namespace) -> int:
    from functools import partial

    from uwbnet.map_cmd import map_recording

    scenario = _load_scenario(args.eval) if args.eval else None
    png = str(_out_path(args.png)) if args.png else None
    run = partial(
        map_recording,
        particles=args.particles,
        seed=args.seed,
        robot=args.robot,
        png=png,
        scenario=scenario,
        smooth=not args.no_smooth,
        localise=args.localise,
        close=not args.no_close,
        bundle_adjust=args.bundle_adjust,
    )
    return _run_offline(args, "mapping", run)


def cmd_eval(args: argparse.Namespace) -> int:
    from fusion_center.offline import evaluate_files

    result = evaluate_files(args.truth, args.tracks, skip=args.skip, cutoff=args.cutoff)
    print(json.dumps(result))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    # Per-core figures of code that runs in the live processes, so with their one BLAS thread
    # (see above cmd_demo); ``bench scale`` and ``bench slam`` start their own processes.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from uwbnet.bench import BENCHES

    result = BENCHES[args.name](seed=args.seed)
    if not args.json:
        for k, v in result.items():
            print(f"{k:>28}: {v}")
    print(json.dumps(result))
    return 0


def _count(value: str) -> int:
    try:
        n = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {value!r}") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0: {value!r}")
    return n


def cmd_scale(args: argparse.Namespace) -> int:
    from uwbnet.scale_cmd import IR_WINDOW, ScaleConfig, ScaleError, run_scale, summary_text

    if args.out:
        _out_path(args.out)
    try:
        summary = run_scale(
            ScaleConfig(
                nodes=args.nodes,
                people=args.people,
                hosts=args.hosts,
                duration=args.duration,
                workers=args.workers,
                nodes_per_process=args.nodes_per_process,
                threads=args.threads,
                spread_slots=args.spread_slots,
                rt_priority=args.rt_priority,
                frame_lag=args.frame_lag,
                frame_wait=args.frame_wait,
                catch_up=args.catch_up,
                batches_per_wake=args.batches_per_wake,
                max_range=args.max_range,
                ir_window=getattr(args, "ir_window", IR_WINDOW),
                pipeline=args.pipeline,
                seed=args.seed,
                out=args.out,
            )
        )
    except ScaleError as exc:
        raise CliError(str(exc)) from None
    if not args.json:
        print(summary_text(summary))
    print(json.dumps(summary))
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
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see above cmd_demo
    from uwbnet.config import SimNodeFile, load_config
    from uwbnet.processes import run_simnode, stop_on_signals

    cfg = load_config(SimNodeFile, args.config, _zenoh_overrides(args))
    with stop_on_signals() as stop:
        return run_simnode(cfg, stop)


def cmd_fusion(args: argparse.Namespace) -> int:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see above cmd_demo
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
    walls = None
    if args.floor_plan:
        from fusion_center.viewer.state import floor_plan

        walls = floor_plan(_load_scenario(args.floor_plan))
    with stop_on_signals() as stop:
        result = run_record(cfg, out, stop, args.duration or math.inf, walls=walls)
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


def cmd_plot(args: argparse.Namespace) -> int:
    from uwbnet import plot_cmd

    out = _out_path(args.out)
    if args.plot_command == "tracks":
        for p in (args.recording, args.tracks):
            if not Path(p).is_file():
                raise CliError(f"no such file: {p}")
        scenario = _load_scenario(args.scenario) if args.scenario else None
        result = plot_cmd.plot_tracks(Path(args.recording), Path(args.tracks), out, scenario)
    elif args.plot_command == "image":
        if not Path(args.npz).is_file():
            raise CliError(f"no such file: {args.npz}")
        result = plot_cmd.plot_image(Path(args.npz), out)
    elif args.plot_command == "channel":
        if not Path(args.recording).is_file():
            raise CliError(f"no such recording: {args.recording}")
        result = plot_cmd.plot_channel(
            Path(args.recording), args.node, out, rx=args.rx, max_range=args.max_range
        )
    else:
        result = plot_cmd.plot_topology(_load_scenario(args.scenario), out)
    print(json.dumps(result))
    return 0


def cmd_topology(args: argparse.Namespace) -> int:
    from uwbnet.topology_cmd import evaluate_scenario, optimize_scenario, print_human

    # 'topology SCENARIO' and 'topology optimize SCENARIO' share one parser: argparse cannot
    # tell a sub-command from an optional positional, so the first word decides here.
    optimize = args.scenario == "optimize"
    name = args.optimize_scenario if optimize else args.scenario
    if optimize and (name is None or args.sensors is None):
        raise CliError("usage: uwbnet topology optimize SCENARIO --sensors K")
    if not optimize and args.optimize_scenario is not None:
        raise CliError(f"unexpected argument {args.optimize_scenario!r} after the scenario")
    if not optimize and (args.sensors is not None or args.add):
        raise CliError("--sensors and --add belong to 'uwbnet topology optimize'")
    if not 10 <= args.grid <= 2000 or min(args.refs) < 1 or max(args.refs) > 50:
        raise CliError("--grid must be 10..2000 and --refs 1..50 points per axis")
    scenario = _load_scenario(name)
    png = _out_path(args.png) if args.png else None
    refs = tuple(args.refs)
    try:
        if optimize:
            result = optimize_scenario(
                scenario,
                args.sensors,
                spacing=args.spacing,
                add=args.add,
                grid=args.grid,
                references=refs,
                png=png,
            )
        else:
            result = evaluate_scenario(
                scenario, grid=args.grid, references=refs, links=args.links, png=png
            )
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if not args.json:
        print_human(result)
    print(json.dumps(result))
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


#: The benchmarks of ``uwbnet bench`` (the keys of ``uwbnet.bench.BENCHES``, which a test
#: checks): listed here so that parsing the command line imports no benchmark module.
BENCH_NAMES = (
    "channel",
    "dsp",
    "fusion",
    "fuzz",
    "hub",
    "imaging",
    "localization",
    "objects",
    "scale",
    "sim",
    "slam",
    "topology",
    "web",
)


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
    d.add_argument("--web-host", default="127.0.0.1", help="address of the web view (0.0.0.0: all)")
    d.add_argument("--record", help="also record the network to this MCAP file")
    d.add_argument("--net", default="demo", help="network name in the key expressions")
    d.add_argument(
        "--method",
        choices=("gmphd", "image"),
        default="gmphd",
        help="fusion method: labelled GM-PHD (9.2) or fused image (9.1)",
    )
    d.add_argument(
        "--image-rate",
        type=float,
        default=0.0,
        help="live Kirchhoff images per second on fusion/image (0: off)",
    )
    d.set_defaults(func=cmd_demo)

    s = sub.add_parser("sim", help="simulate a scenario into an MCAP recording")
    s.add_argument("scenario", help="shipped scenario name or TOML path")
    s.add_argument("--out", required=True, help="output MCAP file")
    s.add_argument("--duration", type=_positive, help="seconds (default: the scenario's)")
    s.add_argument("--seed", type=int, default=1, help="simulation seed")
    s.add_argument("--net", default="demo", help="network name in the topics")
    s.add_argument("--stops", type=int, help="[robot] scenarios: only the first N stops")
    s.add_argument(
        "--snr", type=float, default=30.0, help="[robot] scenarios: in-band SNR, dB (30)"
    )
    s.add_argument(
        "--workers",
        type=int,
        default=2,
        choices=range(1, 65),
        metavar="N",
        help="[robot] scenarios: processes computing the channel (2)",
    )
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
        choices=("mpd", "threshold", "adaptive", "peak", "ml"),
        default="adaptive",
        help="ToA estimator: maximum probability of detection (eq. 4-5), fixed or adaptive "
        "threshold, strongest peak, or ml (multipath fit, docs/localization.md)",
    )
    r.set_defaults(func=cmd_ranging)

    lo = sub.add_parser("localize", help="localize mobile nodes over a recording (RTToA ranges)")
    lo.add_argument("recording", help="MCAP recording with ranging detections")
    lo.add_argument("--out", help="poses JSONL to write")
    lo.add_argument("--method", choices=["lls", "taylor", "aml"], default="taylor")
    lo.add_argument("--no-mitigation", action="store_true", help="use every anchor as LOS")
    lo.add_argument("--table", action="store_true", help="every estimator, with/without mitigation")
    lo.set_defaults(func=cmd_localize)
    im = sub.add_parser("image", help="multistatic image of a recording's impulse responses")
    im.add_argument("recording", help="input MCAP recording (node_info, ir, optional poses)")
    im.add_argument("--out", required=True, help="output .npz (img, x0, y0, dx, dy)")
    im.add_argument(
        "--method",
        choices=("kirchhoff", "xcorr"),
        default="kirchhoff",
        help="Kirchhoff migration (eq. 17) or cross-correlated imaging (eq. 18)",
    )
    im.add_argument("--png", help="also save the image (dB re maximum) as PNG")
    im.add_argument("--nx", type=int, default=400, choices=range(2, 4097), metavar="N")
    im.add_argument("--ny", type=int, default=400, choices=range(2, 4097), metavar="N")
    im.add_argument(
        "--bounds",
        type=float,
        nargs=4,
        metavar=("XMIN", "XMAX", "YMIN", "YMAX"),
        help="image extent, m (default: the antennas' extent plus --margin)",
    )
    im.add_argument("--margin", type=float, default=1.0, help="m around the antennas (1)")
    im.add_argument("--z", type=float, help="height of the image plane, m (mean antenna height)")
    im.add_argument("--raw", action="store_true", help="migrate raw samples, not envelopes")
    im.add_argument(
        "--coherent",
        action="store_true",
        help="kirchhoff: coherent sum of complex-baseband rows, envelope after summation",
    )
    im.add_argument("--pattern", action="store_true", help="weight by the antenna patterns")
    im.add_argument("--gate", type=float, default=0.3, help="m of path after the direct coupling")
    im.add_argument("--workers", type=int, default=2, choices=range(1, 65), metavar="N")
    im.add_argument("--scenario", help="scenario of the recording: print quality figures")
    im.add_argument("--db-range", type=_positive, default=30.0, help="PNG colour range, dB")
    im.set_defaults(func=cmd_image)

    st = sub.add_parser(
        "stationary", help="Pd vs SINR of stationary-target detection along a track (8.2)"
    )
    st.add_argument(
        "--sinr",
        type=float,
        nargs="+",
        default=[-15.0, -12.0, -9.0, -6.0, -3.0, 0.0],
        help="SINR of one impulse response, dB",
    )
    st.add_argument("--pf", type=float, default=1e-3, help="false-alarm probability (1e-3)")
    st.add_argument("--trials", type=int, default=20000, choices=range(100, 10**6), metavar="N")
    st.add_argument("--seed", type=int, default=0)
    st.add_argument("--json", action="store_true", help="print only the JSON line")
    st.set_defaults(func=cmd_stationary)
    mp = sub.add_parser("map", help="UWB SLAM of a robot recording: walls, corners, points, path")
    mp.add_argument("recording", help="input MCAP recording (a robot's ir, optional ir.odom)")
    mp.add_argument("--out", required=True, help="output map.json (first-pose frame)")
    mp.add_argument("--png", help="also draw the map to this PNG")
    mp.add_argument(
        "--association",
        dest="method",
        choices=("auto", "measurement", "state"),
        default="auto",
        help="the filter's data association (6.3): echo groups (measurement space), per pair "
        "(state space), or auto: state when the robot turns in steps of 10 degrees or more",
    )
    mp.add_argument(
        "--localise",
        choices=("auto", "stops", "filter"),
        default="auto",
        help="path estimator: the stop graph (stop-and-turn robots, deterministic), the "
        "particle filter (Section 6), or auto (default): the stop graph when the robot turns in "
        "steps under 10 degrees and its registrations join 3/4 of the stops, else the filter",
    )
    mp.add_argument("--particles", type=int, default=40, help="particles (40)")
    mp.add_argument("--seed", type=int, default=0, help="seed of the particle filter (0)")
    mp.add_argument("--robot", help="robot node id (default: the first mobile node with ir)")
    mp.add_argument("--eval", metavar="SCENARIO", help="score the map against this scenario")
    mp.add_argument(
        "--no-smooth",
        action="store_true",
        help="skip the joint least-squares smoothing of path and map (the filter's own map)",
    )
    mp.add_argument(
        "--no-close",
        action="store_true",
        help="leave the walls' ends where their echoes put them (no closing of the outline: "
        "walls that meet extended to their corner)",
    )
    mp.add_argument(
        "--bundle-adjust",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="the stop graph: adjust its path over every echo pair after the refinement "
        "(default: on; see docs/mapping.md)",
    )
    mp.set_defaults(func=cmd_map)

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
    r.add_argument(
        "--floor-plan", metavar="SCENARIO", help="walls of this scenario on the /viz/walls channel"
    )
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

    pl = sub.add_parser("plot", help="figures (PNG/SVG/PDF): tracks, image, channel, topology")
    psub = pl.add_subparsers(dest="plot_command", required=True, parser_class=_Parser)
    pt = psub.add_parser("tracks", help="tracks vs the recording's truth")
    pt.add_argument("recording", help="MCAP recording with truth messages")
    pt.add_argument("tracks", help="tracks JSONL ('uwbnet track')")
    pt.add_argument("--scenario", help="draw this scenario's walls")
    pi = psub.add_parser("image", help="an imaging result (.npz with img, x0, y0, dx, dy)")
    pi.add_argument("npz", help="image .npz (PROTOCOL.md image fields)")
    pc = psub.add_parser("channel", help="radargram of a node's impulse responses")
    pc.add_argument("recording", help="MCAP recording with ir messages")
    pc.add_argument("--node", required=True, help="node id")
    pc.add_argument("--rx", help="receiving antenna (default: the first)")
    pc.add_argument("--max-range", type=_positive, default=30.0, help="bistatic range shown, m")
    po = psub.add_parser("topology", help="deployment layout of a scenario")
    po.add_argument("scenario", help="shipped scenario name or TOML path")
    for sp in (pt, pi, pc, po):
        sp.add_argument("--out", required=True, help="output figure (.png, .svg or .pdf)")
        sp.set_defaults(func=cmd_plot)

    b = sub.add_parser("bench", help="benchmarks; JSON figures on the last line")
    b.add_argument("name", choices=BENCH_NAMES)
    b.add_argument("--json", action="store_true", help="print only the JSON line")
    b.add_argument("--seed", type=int, default=0)
    b.set_defaults(func=cmd_bench)

    tp = sub.add_parser(
        "topology",
        help="resolution and ghost maps of a deployment (ambiguity function); placement",
        usage="uwbnet topology SCENARIO [options]\n"
        "       uwbnet topology optimize SCENARIO --sensors K [options]",
        description="'uwbnet topology SCENARIO': resolution and ghost-level maps of the "
        "scenario's deployment. 'uwbnet topology optimize SCENARIO --sensors K': choose K "
        "sensor sites on the walls (greedy + local refinement) and compare with a naive "
        "placement.",
    )
    tp.add_argument("scenario", help="shipped scenario name or TOML path, or 'optimize'")
    tp.add_argument("optimize_scenario", nargs="?", help=argparse.SUPPRESS)
    tp.add_argument("--png", help="save the maps to this PNG file")
    tp.add_argument("--json", action="store_true", help="print only the JSON line")
    tp.add_argument("--grid", type=int, default=200, help="ghost-search grid points per axis")
    tp.add_argument("--refs", type=int, nargs=2, default=(8, 6), metavar=("MX", "MY"))
    tp.add_argument("--links", choices=("all", "own"), default="all", help="who hears whom")
    tp.add_argument("--sensors", type=int, help="optimize: number of sites to place")
    tp.add_argument("--spacing", type=_positive, default=1.0, help="optimize: site spacing, m")
    tp.add_argument("--add", action="store_true", help="optimize: add to the scenario's nodes")
    tp.set_defaults(func=cmd_topology)
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

    sc = sub.add_parser("scale", help="N simulated nodes, M people, fusion: latency, drops, CPU")
    sc.add_argument("--nodes", type=_count, required=True, help="simulated bat-type nodes")
    sc.add_argument("--people", type=_count, default=2, help="walking people")
    sc.add_argument("--hosts", type=_count, default=1, help="network namespaces (root if > 1)")
    sc.add_argument("--duration", type=_positive, default=10.0, help="measured seconds")
    sc.add_argument("--workers", type=_count, default=1, help="fusion cell workers (1: one center)")
    sc.add_argument("--nodes-per-process", type=_count, default=8, help="nodes per process")
    sc.add_argument(
        "--threads",
        choices=("process", "agent", "batch"),
        default="batch",
        help="batch (default): one acquisition thread per node process, serving its nodes' "
        "slots of a frame together; agent: one per node agent; process: one per node "
        "process, a slot per wake-up",
    )
    sc.add_argument(
        "--spread-slots",
        action="store_true",
        help="a node process's nodes spread over the frame (default: adjacent TDMA slots)",
    )
    sc.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="P",
        help="run every process SCHED_FIFO at priority P (1-99, root; default 0: off)",
    )
    sc.add_argument(
        "--frame-lag",
        type=int,
        default=2,
        help="the fusion center fuses a frame once a detection of the frame this many frames "
        "later arrives (default 2)",
    )
    sc.add_argument(
        "--frame-wait",
        type=int,
        default=0,
        metavar="W",
        help="an incomplete frame waits up to W frames more for a node whose detection may "
        "still be in flight (default 0: off)",
    )
    sc.add_argument(
        "--catch-up",
        type=float,
        default=0.0,
        metavar="S",
        help="--threads batch: still serve a slot whose start passed less than S seconds ago "
        "(default 0: skip it)",
    )
    sc.add_argument(
        "--batches-per-wake",
        type=int,
        default=1,
        metavar="B",
        help="--threads batch: a node process serves B batches (10 ms of slots each; 1-8) "
        "per wake-up, each published at its own slots (default 1)",
    )
    sc.add_argument(
        "--max-range",
        type=float,
        default=None,
        metavar="M",
        help="the node DSP processes bistatic ranges up to M metres only (default: the whole "
        "impulse response; people beyond 20 m are not simulated, so 45 m loses no echo)",
    )
    sc.add_argument(
        "--ir-window",
        type=_ir_window,
        # absent: scale_cmd.IR_WINDOW (not imported here: the CLI starts without numpy)
        default=argparse.SUPPRESS,
        metavar="M",
        help="the simulated radars deliver only the impulse-response samples up to M metres "
        "of bistatic range, their noise drawn for those only (default 45; 'full': the whole "
        "175 m period)",
    )
    sc.add_argument(
        "--pipeline",
        action="store_true",
        help="--threads batch: one thread per node process publishes a frame's messages at "
        "their slots and then computes the next frame (one wake-up per frame, not two)",
    )
    sc.add_argument("--seed", type=int, default=1)
    sc.add_argument("--out", help="directory for tracks.jsonl and process logs (default: temp)")
    sc.add_argument("--json", action="store_true", help="print only the JSON line")
    sc.set_defaults(func=cmd_scale)
    return p


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exception types that are the user's input, reported as one line."""
    from fusion_center.image_input import ImagingError
    from fusion_center.offline import TrackingError
    from fusion_center.offline_localization import LocalizationError
    from node_agent.drivers.base import DriverError
    from node_agent.offline import RangingError
    from protocol import ProtocolError
    from sim_nodes.scene import ScenarioError
    from uwbnet.config import ConfigError
    from uwbnet.map_cmd import MappingError
    from uwbnet.plot_cmd import PlotError

    return (
        PlotError,
        CliError,
        ConfigError,
        ProtocolError,
        ScenarioError,
        TrackingError,
        LocalizationError,
        ImagingError,
        RangingError,
        MappingError,
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
