"""Where an armnet program finds its NATS server: its own flag or variable, then ``NATS_URL``.

One rule for the client, the node agent and the FMS, so the environment ``armnet dev up``
prints (``export NATS_URL=...``) reaches every one of them, while a deployment can still
give each its own URL (the Helm chart sets ``ARMNET_AGENT_NATS_URL`` and
``ARMNET_FMS_NATS_URL``: each carries that component's NATS user). Pure: it reads only
the mapping it is given.
"""

from __future__ import annotations

from collections.abc import Mapping

SHARED_ENV = "NATS_URL"
"""The variable every armnet program falls back to (``armnet dev up`` exports it)."""


def nats_url_from(flag: str | None, env: Mapping[str, str], own_env: str) -> str | None:
    """``flag``, else ``env[own_env]``, else ``env["NATS_URL"]``; an empty value counts as unset."""
    if flag:
        return flag
    return next((env[name] for name in (own_env, SHARED_ENV) if env.get(name)), None)
