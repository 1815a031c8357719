"""Reading an ``.rrd`` back with rerun-sdk's own reader (``rerun.dataframe``), for the view tests.

What the tests compare: per entity path, the rows in ``frame`` order with the
logged value (a scalar, or an image's bytes with its media type or format).
rerun-sdk 0.26 (LeRobot 0.4.4's series, docs/lerobot-compatibility.md) reads a
recording as one Arrow table indexed by a timeline: a column per entity and
component (``/path:Archetype:component``), null in the rows where that entity
logged nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def recorded(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """``{"/entity": [(frame, value), ...]}`` for every entity logged on the ``frame`` timeline."""
    import rerun.dataframe

    table = rerun.dataframe.load_recording(str(path)).view(index="frame", contents="/**").select().read_all()
    frames = table.column("frame").to_pylist()
    columns: dict[str, dict[str, list[Any]]] = {}
    for field in table.schema:
        meta = {k.decode(): v.decode() for k, v in (field.metadata or {}).items()}
        if meta.get("rerun:kind") != "data" or meta["rerun:entity_path"].startswith("/__"):
            continue
        columns.setdefault(meta["rerun:entity_path"], {})[meta["rerun:component"]] = (
            table.column(field.name).to_pylist())
    rows: dict[str, list[tuple[int, Any]]] = {}
    for entity, components in columns.items():
        for i, frame in enumerate(frames):
            if any(values[i] is not None for values in components.values()):
                rows.setdefault(entity, []).append((frame, _value(components, i)))
    return {entity: sorted(values, key=lambda row: row[0]) for entity, values in rows.items()}


def _value(components: dict[str, list[Any]], row: int) -> Any:
    if "Scalars:scalars" in components:
        return components["Scalars:scalars"][row][0]
    if "EncodedImage:blob" in components:
        blob = components["EncodedImage:blob"][row][0]
        return ("encoded", components["EncodedImage:media_type"][row][0], bytes(blob))
    if "Image:buffer" in components:
        fmt = components["Image:format"][row][0]
        return ("image", fmt["width"], fmt["height"], bytes(components["Image:buffer"][row][0]))
    raise AssertionError(f"unexpected components in the recording: {sorted(components)}")
