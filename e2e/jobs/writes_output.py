"""Writes a small dataset-shaped tree into its output directory, and a link out of it.

The node agent must store the tree with each file's checksum and leave the link out
(it points at a file of the host the job must never hand over).
"""

import json
import os
from pathlib import Path

from armnet_runtime import Context, main


@main
def run(ctx: Context):
    out = Path(os.environ["ARMNET_OUTPUT_DIR"])
    (out / "data" / "chunk-000").mkdir(parents=True)
    (out / "data" / "chunk-000" / "episode_000000.parquet").write_bytes(bytes(range(256)) * 16)
    (out / "meta").mkdir()
    (out / "meta" / "info.json").write_text(json.dumps({"fps": 30, "episodes": 1}))
    (out / "host-hostname").symlink_to("/etc/hostname")
    return {"wrote": 2}
