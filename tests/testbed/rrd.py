"""Reading an ``.rrd`` back with rerun-sdk's own reader (``rerun.chunk.RrdReader``), for the view tests.

What the tests compare: per entity path, the rows in ``frame`` order with the
logged value (a scalar, or an image's bytes with its media type or format).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def recorded(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """``{"/entity": [(frame, value), ...]}`` for every non-static entity of the file's recording."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[tuple[int, Any]]] = {}
    for chunk in RrdReader(path).stream():
        if chunk.is_static or "frame" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        frames = batch.column("frame").to_pylist()
        for i, frame in enumerate(frames):
            rows.setdefault(chunk.entity_path, []).append((frame, _value(batch, i)))
    return {entity: sorted(values, key=lambda row: row[0]) for entity, values in rows.items()}


def _value(batch: Any, row: int) -> Any:
    names = set(batch.schema.names)
    if "Scalars:scalars" in names:
        return batch.column("Scalars:scalars")[row].as_py()[0]
    if "EncodedImage:blob" in names:
        blob = batch.column("EncodedImage:blob")[row].as_py()[0]
        return ("encoded", batch.column("EncodedImage:media_type")[row].as_py()[0], bytes(blob))
    if "Image:buffer" in names:
        fmt = batch.column("Image:format")[row].as_py()[0]
        return ("image", fmt["width"], fmt["height"], bytes(batch.column("Image:buffer")[row].as_py()[0]))
    raise AssertionError(f"unexpected columns in the recording: {sorted(names)}")
