"""Operator settings: flags win over ``ARMNET_OPERATOR_*`` environment variables.

Pydantic validates them at the boundary so a typo fails at start-up with the
name of the setting, not as a strange scheduling decision hours later.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping
from datetime import timedelta
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .errors import PermanentError
from .model import Timing

ENV_PREFIX = "ARMNET_OPERATOR_"


class OperatorSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    heartbeat_timeout: float = Field(30.0, gt=0, description="seconds without a Cell heartbeat before it is Offline")
    claim_grace: float = Field(10.0, gt=0, description="seconds a half-done binding is left alone before repair")
    lost_grace: float = Field(60.0, ge=0, description="seconds past the heartbeat timeout before a running job fails as lost")
    cancel_force_after: float = Field(60.0, ge=0, description="seconds an unconfirmed cancel on a lost cell waits before it is forced")
    default_ttl: float | None = Field(86400.0, ge=0, description="seconds finished RobotJobs are kept when they set no ttlSecondsAfterFinished (none: forever)")
    episode_wait: float = Field(120.0, ge=0, le=86400, description="seconds a preempted job may run on to its next episode boundary before its grace window opens")
    reconcile_period: float = Field(5.0, gt=0, description="seconds between full reconciles when nothing changes")
    position_refresh: float = Field(5.0, ge=0, description="minimum seconds between queuePosition-only updates of one job")
    quota_refresh: float = Field(30.0, gt=0, description="seconds between writes of a CellQuota's usage when nothing else in its status changes")
    namespaces: tuple[str, ...] = Field((), description="namespaces to watch for RobotJobs (empty: all)")
    metrics_port: int = Field(8080, ge=0, le=65535, description="port of /metrics (0: off)")
    metrics_address: str = "0.0.0.0"
    webhook_port: int = Field(0, ge=0, le=65535, description="HTTPS port of the RobotJob admission webhook (0: off)")
    webhook_address: str = Field("0.0.0.0", description="address the admission webhook listens on")
    webhook_cert_file: str | None = Field(None, description="PEM serving certificate of the admission webhook")
    webhook_key_file: str | None = Field(None, description="PEM private key of that certificate")
    lease_name: str = "armnet-operator"
    lease_namespace: str = Field("armnet-system", description="namespace of the leader-election Lease")
    lease_duration: float = Field(15.0, gt=0, description="seconds a leader holds the Lease without renewing")
    identity: str = Field(default_factory=lambda: f"{socket.gethostname()}-{os.getpid()}")
    kubeconfig: str | None = None

    @field_validator("namespaces", mode="before")
    @classmethod
    def _split(cls, value: Any) -> Any:
        if isinstance(value, str):
            return tuple(part.strip() for part in value.split(",") if part.strip())
        return value

    @field_validator("default_ttl", mode="before")
    @classmethod
    def _none(cls, value: Any) -> Any:
        return None if isinstance(value, str) and value.lower() in ("", "none", "off") else value

    @model_validator(mode="after")
    def _webhook_needs_a_certificate(self) -> OperatorSettings:
        if self.webhook_port and not (self.webhook_cert_file and self.webhook_key_file):
            raise ValueError("the admission webhook (webhook_port) needs webhook_cert_file and webhook_key_file: "
                             "the API server only calls webhooks over TLS")
        return self

    @property
    def timing(self) -> Timing:
        return Timing(
            heartbeat_timeout=timedelta(seconds=self.heartbeat_timeout),
            claim_grace=timedelta(seconds=self.claim_grace),
            lost_grace=timedelta(seconds=self.lost_grace),
            cancel_force_after=timedelta(seconds=self.cancel_force_after),
            default_ttl=None if self.default_ttl is None else timedelta(seconds=self.default_ttl),
            episode_wait=timedelta(seconds=self.episode_wait),
        )


def load_settings(
    overrides: Mapping[str, Any] | None = None, environ: Mapping[str, str] | None = None
) -> OperatorSettings:
    """Merge env (``ARMNET_OPERATOR_HEARTBEAT_TIMEOUT`` ...) with explicit overrides."""
    environ = os.environ if environ is None else environ
    values: dict[str, Any] = {}
    for name in OperatorSettings.model_fields:
        raw = environ.get(ENV_PREFIX + name.upper())
        if raw is not None:
            values[name] = raw
    values.update({k: v for k, v in (overrides or {}).items() if v is not None})
    try:
        return OperatorSettings.model_validate(values)
    except ValidationError as error:
        problems = "; ".join(
            f"{ENV_PREFIX}{'.'.join(map(str, e['loc'])).upper()} (--{'-'.join(map(str, e['loc'])).replace('_', '-')}): {e['msg']}"
            if e["loc"] else str(e["msg"])
            for e in error.errors()
        )
        raise PermanentError(f"invalid operator settings: {problems}") from error
