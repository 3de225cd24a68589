"""``uwbnet localize``: localization of mobile nodes over a recording, and its evaluation.

``uwbnet localize FILE.mcap --out POSES.jsonl [--method lls|taylor|aml] [--no-mitigation]``
writes one JSON line per pose update and prints the counts, plus the evaluation against the
recording's truth when it has one (:func:`fusion_center.offline_localization.
evaluate_localization`). ``uwbnet localize FILE.mcap --table`` prints the evaluation of every
estimator with and without NLOS mitigation (markdown, then JSON on the last line).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

from fusion_center.localization.estimators import LOCATORS
from fusion_center.offline_localization import (
    LocalizationError,
    evaluate_localization,
    localize_recording,
)


def localization_table(recording: str | Path) -> list[dict[str, Any]]:
    """The evaluation of every estimator, with and without mitigation, on one recording."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "poses.jsonl"
        for method in LOCATORS:
            for mitigate in (False, True):
                localize_recording(recording, out, method=method, mitigate=mitigate)
                rows.append(
                    {
                        "method": method,
                        "mitigation": mitigate,
                        **evaluate_localization(recording, out),
                    }
                )
    return rows


def table_lines(rows: list[dict[str, Any]]) -> list[str]:
    """A markdown table of :func:`localization_table` rows, then their JSON."""
    cols = ["method", "mitigation", "rmse", "fix_rmse", "crlb", "nlos_detection",
            "nlos_false_alarm"]  # fmt: skip
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r[c]) for c in cols) + " |" for r in rows]
    return [*lines, json.dumps(rows)]


def localize(src: Path, out: Path, *, method: str, mitigate: bool) -> dict[str, Any]:
    """Localize a recording into ``out``; the counts and, with truth, the evaluation."""
    stats = localize_recording(src, out, method=method, mitigate=mitigate)
    result: dict[str, Any] = {"out": str(out), **stats.as_dict()}
    if stats.poses:
        try:
            result.update(evaluate_localization(src, out))
        except LocalizationError as exc:
            result["evaluation"] = str(exc)
    return result
