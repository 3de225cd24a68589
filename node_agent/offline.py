"""Offline per-impulse-response ranging of a recording: ``uwbnet ranging``.

For every row of every ``ir`` message, one JSON line
``{"t", "node", "tx", "rx", "range", "los", "method"}``: the first-path bistatic path length in
metres, :math:`c (t_0 + \\hat\\tau)`, with ``t0``, ``fs``, band and carrier from the receiving
node's ``node_info.radar``, and the per-link LOS decision from the impulse response's shape
(:class:`node_agent.dsp.ranging.FirstPathRanger`). ``range`` is null where no first path rises
above the noise.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Callable
from pathlib import Path

from node_agent.core import NodeConfigError, radar_params
from node_agent.dsp.ranging import FirstPathRanger
from protocol import Ir, NodeInfo
from protocol.recording import decoded_messages

log = logging.getLogger(__name__)


class RangingError(ValueError):
    """A recording cannot be ranged (one-line message)."""


@dataclasses.dataclass(slots=True)
class RangingStats:
    """Counts of an offline ranging run."""

    messages: int = 0
    ir: int = 0
    lines: int = 0
    los: int = 0
    no_path: int = 0
    rejected: int = 0
    nodes: int = 0

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


def _number(x: float) -> float | None:
    return round(float(x), 6) if math.isfinite(x) else None


def range_recording(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    method: str = "adaptive",
    progress: Callable[[int], None] | None = None,
) -> RangingStats:
    """Range every impulse response of a recording into a JSONL file.

    The output appears under ``out`` only when complete (written to ``out.partial`` and
    renamed). An ``ir`` before its node's ``node_info``, with a sample count other than
    ``node_info.radar.n``, or with NaN/Inf is counted in ``rejected`` and logged; a corrupt
    recording raises :class:`protocol.RecordingError`, a recording without any ``ir``
    :class:`RangingError`.
    """
    out = Path(out)
    partial = out.with_name(out.name + ".partial")
    stats = RangingStats()
    rangers: dict[str, FirstPathRanger] = {}
    infos: set[str] = set()
    try:
        with open(partial, "w", encoding="utf-8") as f:
            for msg in decoded_messages(path, ("node_info", "ir"), stats, progress):
                if isinstance(msg, NodeInfo):
                    infos.add(msg.src)
                    try:
                        rangers[msg.src] = FirstPathRanger(radar_params(msg), method=method)
                    except NodeConfigError as exc:
                        rangers.pop(msg.src, None)
                        stats.rejected += 1
                        log.warning("node_info rejected: %s", exc)
                    continue
                if not isinstance(msg, Ir):
                    continue
                stats.ir += 1
                ranger = rangers.get(msg.src)
                if ranger is None:
                    stats.rejected += 1
                    log.warning("ir of %s without a usable node_info: rejected", msg.src)
                    continue
                try:
                    result = ranger.process(msg.h)
                except ValueError as exc:
                    stats.rejected += 1
                    log.warning("ir of %s rejected: %s", msg.src, exc)
                    continue
                for name, r, los in zip(msg.rx, result.range, result.los, strict=True):
                    rng = _number(r)
                    line = {
                        "t": msg.t,
                        "node": msg.src,
                        "tx": msg.tx,
                        "rx": name,
                        "range": rng,
                        "los": bool(los),
                        "method": method,
                    }
                    f.write(json.dumps(line, separators=(",", ":")) + "\n")
                    stats.lines += 1
                    stats.los += bool(los)
                    stats.no_path += rng is None
            if stats.ir == 0:
                raise RangingError(f"{path}: no ir messages")
        stats.nodes = len(infos)
        os.replace(partial, out)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return stats
