"""Validation of ``/viz`` documents against Foxglove's published JSON schemas (vendored)."""

from __future__ import annotations

import base64
import json
from functools import cache
from typing import Any

import jsonschema

from fusion_center.viewer.foxglove import foxglove_schema


@cache
def validator(name: str) -> Any:
    schema = json.loads(foxglove_schema(name))
    cls = jsonschema.validators.validator_for(schema, default=jsonschema.Draft202012Validator)
    cls.check_schema(schema)
    return cls(schema)


def check(name: str, doc: dict[str, Any]) -> None:
    """Raise ``jsonschema.ValidationError`` unless ``doc`` is a valid ``name`` message; for a
    Grid also check that its base64 data holds whole rows."""
    validator(name).validate(doc)
    if name == "foxglove.Grid":
        data = base64.b64decode(doc["data"], validate=True)
        assert len(data) % doc["row_stride"] == 0
        assert doc["row_stride"] == doc["column_count"] * doc["cell_stride"]
