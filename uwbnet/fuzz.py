"""Coverage-guided fuzzing (atheris, libFuzzer) of the two parsers that take bytes from outside.

    python -m uwbnet.fuzz decoder|serial --runs N [--seed S] [--corpus DIR]

``decoder``: :func:`protocol.decode` on arbitrary bytes must return a message or raise a
:class:`~protocol.ProtocolError`, nothing else. ``serial``: :class:`FrameParser` fed arbitrary
bytes in arbitrary pieces must never raise, must keep its buffer below one maximal frame, and
the payload decoders must raise only :class:`FrameError`. Any other exception is a crash
(libFuzzer writes the input to ``crash-*``); an input slower than 5 s is a hang. The last line
of stderr is libFuzzer's ``Done N runs in S second(s)``. ``uwbnet bench fuzz`` runs both.

atheris is an optional dependency (``pip install 'uwbnet[fuzz]'``).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

GOLDEN = Path(__file__).resolve().parents[1] / "tests" / "data" / "golden"


def _decoder_target() -> object:
    import protocol
    from protocol import ProtocolError

    def target(data: bytes) -> None:
        try:
            protocol.decode(data)
        except ProtocolError:
            pass

    return target


def _serial_target() -> object:
    import atheris

    from node_agent.drivers import serial_frames as sf

    def target(data: bytes) -> None:
        fdp = atheris.FuzzedDataProvider(data)
        max_payload = fdp.ConsumeIntInRange(0, 4096)
        step = fdp.ConsumeIntInRange(1, 64)
        stream = fdp.ConsumeBytes(fdp.remaining_bytes())
        parser = sf.FrameParser(max_payload=max_payload)
        for i in range(0, len(stream), step):
            for frame in parser.feed(stream[i : i + step]):
                for decode in (sf.decode_info, sf.decode_ir, sf.decode_trigger):
                    try:
                        decode(frame.payload)
                    except sf.FrameError:
                        pass
            if len(parser._buf) > sf.HEADER_SIZE + max_payload + sf.CRC_SIZE:
                raise AssertionError(f"parser buffer grew to {len(parser._buf)} B")

    return target


def _serial_seeds() -> list[bytes]:
    import numpy as np

    from node_agent.drivers import serial_frames as sf

    info = sf.DeviceInfo(fs=7e9, t0=0.0, f_low=0.0, f_high=3.5e9, rate=50.0, n=8, n_rx=2)
    frames = [
        sf.encode_frame(sf.FrameType.INFO, 1, sf.encode_info(info)),
        sf.encode_frame(sf.FrameType.TRIGGER, 2, sf.encode_trigger(7, 1)),
        sf.encode_frame(sf.FrameType.IR, 3, sf.encode_ir(7, np.ones((2, 8), np.float32))),
    ]
    # Leading bytes for the data provider (max_payload, step), then the stream.
    return [b"\x00\x04\x00\x00\x00\x00\x00\x10" + f + b"\x01garbage" + f for f in frames]


def main(argv: list[str] | None = None) -> None:
    """Run one fuzz target; exits with libFuzzer's status (0: no crash, no hang)."""
    import atheris

    p = argparse.ArgumentParser(prog="python -m uwbnet.fuzz")
    p.add_argument("target", choices=("decoder", "serial"))
    p.add_argument("--runs", type=int, default=100_000)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--corpus", help="corpus directory (default: a temporary copy of the seeds)")
    args = p.parse_args(argv)
    corpus = Path(args.corpus) if args.corpus else Path(tempfile.mkdtemp(prefix="uwbfuzz-"))
    corpus.mkdir(parents=True, exist_ok=True)
    if args.target == "decoder":
        for f in GOLDEN.glob("*.msgpack"):
            shutil.copy(f, corpus / f.name)
        target = _decoder_target()
    else:
        for i, seed in enumerate(_serial_seeds()):
            (corpus / f"seed{i}").write_bytes(seed)
        target = _serial_target()
    libfuzzer_args = [
        sys.argv[0],
        str(corpus),
        f"-runs={args.runs}",
        f"-seed={args.seed}",
        "-timeout=5",
        "-max_len=4096",
        "-print_final_stats=1",
    ]
    # Instrument what is loaded now (the target's modules): libFuzzer's coverage guidance.
    atheris.instrument_all()
    atheris.Setup(libfuzzer_args, target)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
