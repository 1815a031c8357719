"""Replaying packets into rerun-sdk writes an .rrd that rerun's own reader reads back as logged."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from armnet_client.errors import RerunMissing
from armnet_client.rerun_sink import Replayed, replay
from armnet_runtime.rerun import ENCODING_JPEG, ENCODING_RAW_U8, Entry, ImageData, Packet
from armnet_testbed.rrd import recorded

pytestmark = pytest.mark.unit

T0 = 1_700_000_000_000_000_000


def _packets() -> list[Packet]:
    return [
        Packet("uid", T0, 0, 0, (Entry("action.gripper.pos", scalar=0.5),
                                 Entry("observation.front", image=ImageData(2, 1, 3, ENCODING_JPEG, b"\xff\xd8jpeg")))),
        Packet("uid", T0 + 10**8, 3, 2, (Entry("action.gripper.pos", scalar=1.5),
                                         Entry("observation.wrist", image=ImageData(2, 1, 3, ENCODING_RAW_U8, bytes(range(6)))),
                                         Entry("observation.bad", image=ImageData(4, 4, 3, ENCODING_RAW_U8, b"\x00")))),
    ]


def test_a_saved_recording_reads_back_with_every_entry_at_its_frame(tmp_path: Path) -> None:
    require_rerun()
    out = tmp_path / "out.rrd"

    done = replay(_packets(), app_id="armnet-test", save=str(out))

    assert done == Replayed(packets=2, skipped=1, dropped=2)
    assert recorded(out) == {
        "/action.gripper.pos": [(0, 0.5), (3, 1.5)],
        "/observation.front": [(0, ("encoded", "image/jpeg", b"\xff\xd8jpeg"))],
        "/observation.wrist": [(3, ("image", 2, 1, bytes(range(6))))],
    }


def test_without_rerun_sdk_it_says_what_to_install(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "rerun", None)  # what `import rerun` meets where it is not installed

    with pytest.raises(RerunMissing, match=r"pip install 'armnet-runtime\[view\]'.*--dump"):
        replay(_packets(), app_id="armnet-test", save=str(tmp_path / "out.rrd"))
    assert not (tmp_path / "out.rrd").exists()


def require_rerun() -> None:
    """rerun-sdk is installed by scripts/setup.sh: missing, it is a failure with the fix, not a skip."""
    import importlib.util

    if importlib.util.find_spec("rerun") is None:
        pytest.fail("rerun-sdk is missing: run scripts/setup.sh (or pip install 'armnet-runtime[view]')",
                    pytrace=False)
