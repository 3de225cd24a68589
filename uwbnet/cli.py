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
from collections.abc import Sequence
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


def cmd_track(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from fusion_center.offline import track_recording

    src = Path(args.recording)
    if not src.is_file():
        raise CliError(f"no such recording: {src}")
    out = _out_path(args.out)
    size = src.stat().st_size
    with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("tracking", total=size)
        stats = track_recording(
            src, out, method=args.method, progress=lambda n: progress.advance(task, n)
        )
    print(json.dumps({"out": str(out), **stats.as_dict()}))
    return 0


def cmd_ranging(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from node_agent.offline import range_recording

    src = Path(args.recording)
    if not src.is_file():
        raise CliError(f"no such recording: {src}")
    out = _out_path(args.out)
    size = src.stat().st_size
    with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("ranging", total=size)
        stats = range_recording(
            src, out, method=args.method, progress=lambda n: progress.advance(task, n)
        )
    print(json.dumps({"out": str(out), "method": args.method, **stats.as_dict()}))
    return 0


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
        default="mpd",
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

    b = sub.add_parser("bench", help="benchmarks; JSON figures on the last line")
    b.add_argument("name", choices=("dsp", "fusion", "sim"))
    b.add_argument("--json", action="store_true", help="print only the JSON line")
    b.add_argument("--seed", type=int, default=0)
    b.set_defaults(func=cmd_bench)
    return p


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exception types that are the user's input, reported as one line."""
    from fusion_center.offline import TrackingError
    from node_agent.drivers.base import DriverError
    from node_agent.offline import RangingError
    from protocol import ProtocolError
    from sim_nodes.scene import ScenarioError

    return (
        CliError,
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
