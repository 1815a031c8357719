"""A local cell file's ``reset``: a scripted reset reaches the connector, one that cannot work is refused."""

from __future__ import annotations

from pathlib import Path

import pytest
from armnet_launch.cell_spec import LocalCellError, LocalCellFile, plan_layout, resolve_spec
from armnet_launch.sim_cell import build_connector_config

pytestmark = pytest.mark.unit

COMPLETION = {"camera": "front", "region": {"left": 0.7, "top": 0.1, "width": 0.1, "height": 0.1},
              "colour": {"hueMin": 170, "hueMax": 8}}


def spec_of(preset: str, **file: object) -> object:
    return resolve_spec(embodiment=None, preset=preset, task=None, grace_seconds=None,
                        cell_file=LocalCellFile.model_validate(file))


def test_a_bimanual_cell_file_s_scripted_reset_reaches_its_connector() -> None:
    reset = {"mode": "Scripted", "poses": [{"left_elbow_flex": 10, "right_elbow_flex": -10}]}
    spec = resolve_spec(embodiment=None, preset="bimanual_so101", task=None, grace_seconds=None,
                        cell_file=LocalCellFile.model_validate({"completion": COMPLETION, "reset": reset}))
    layout = plan_layout(spec, Path("/tmp/armnet-reset-plan"))
    config = build_connector_config(spec, layout, {"left": "/dev/pts/1", "right": "/dev/pts/2"})
    assert config.reset is not None and config.reset.poses == ({"left_elbow_flex": 10, "right_elbow_flex": -10},)


@pytest.mark.parametrize(("preset", "file", "says"), [
    ("so101", {"reset": {"mode": "Scripted", "poses": [{"elbow_flex": 10}]}}, "needs the cell's completion monitor"),
    ("bimanual_so101", {"completion": COMPLETION, "reset": {"mode": "Scripted", "poses": [{"elbow_flex": 10}]}},
     "'elbow_flex' is not a joint of this cell"),
])
def test_a_cell_file_whose_scripted_reset_cannot_work_is_refused_saying_why(
    preset: str, file: dict[str, object], says: str,
) -> None:
    with pytest.raises(LocalCellError, match=says):
        spec_of(preset, **file)
