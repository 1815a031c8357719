"""Kubernetes-convention conditions on status bodies: the core's helpers (``armnet_core.conditions``).

``set_condition`` edits a ``status.conditions`` list in place and returns
whether anything changed, so callers patch only when needed. The transition
time moves only when ``status`` flips, as the API conventions ask; messages are
truncated so a chatty reason never bloats etcd. The node agent writes a Cell's
conditions with the same rule, from the same module.
"""

from __future__ import annotations

from armnet_core.conditions import (
    MAX_MESSAGE,
    find_condition,
    is_true,
    remove_condition,
    set_condition,
)

__all__ = ["MAX_MESSAGE", "find_condition", "is_true", "remove_condition", "set_condition"]
