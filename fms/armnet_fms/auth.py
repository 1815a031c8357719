"""Who is the cell operator: tokens from a Secret, signed session cookies, CSRF tokens, a trusted header.

Pure (standard library only): the web layer passes in what the request carries
and gets an operator name or None. Tokens are compared in constant time;
sessions and CSRF tokens are HMACs under a key only the service knows, so a
tenant who can reach the port still gets nothing without a token.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
from collections.abc import Mapping
from dataclasses import dataclass, field

OPERATOR_NAME_MAX = 64


class AuthConfigError(ValueError):
    """The operators' tokens or the auth settings cannot be used; the message says how to fix them."""


@dataclass(frozen=True)
class AuthSettings:
    """``tokens`` maps a token to the operator's name; ``trusted_header`` names the auth proxy's user header."""

    secret_key: bytes
    tokens: Mapping[str, str] = field(default_factory=dict)
    trusted_header: str = ""
    session_ttl_s: int = 12 * 3600


def parse_tokens(text: str) -> dict[str, str]:
    """``<operator>:<token>`` lines (blank lines and ``#`` comments skipped) -> {token: operator}."""
    tokens: dict[str, str] = {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, token = line.partition(":")
        name, token = name.strip(), token.strip()
        if not sep or not valid_operator(name) or len(token) < 16:
            raise AuthConfigError(
                f"operators file line {number}: expected '<operator>:<token>' with a name of letters, digits, "
                "'.', '-', '_' or '@' and a token of at least 16 characters")
        tokens[token] = name
    return tokens


def valid_operator(name: str) -> bool:
    return 0 < len(name) <= OPERATOR_NAME_MAX and all(c.isalnum() or c in ".-_@" for c in name)


def operator_for_token(settings: AuthSettings, presented: str) -> str | None:
    """The operator whose token this is; every known token is compared, in constant time."""
    found = None
    for token, name in settings.tokens.items():
        if hmac.compare_digest(token.encode(), presented.encode()):
            found = name
    return found


def bearer(authorization: str) -> str:
    scheme, _, value = authorization.partition(" ")
    return value.strip() if scheme.lower() == "bearer" else ""


def _mac(settings: AuthSettings, *parts: str) -> str:
    digest = hmac.new(settings.secret_key, "|".join(parts).encode(), hashlib.sha256).digest()
    return base64.urlsafe_b64encode(digest).decode().rstrip("=")


def make_session(settings: AuthSettings, operator: str, now: float) -> str:
    expires = str(int(now) + settings.session_ttl_s)
    return f"{operator}|{expires}|{_mac(settings, 'session', operator, expires)}"


def session_operator(settings: AuthSettings, cookie: str, now: float) -> str | None:
    """The operator of a valid, unexpired session cookie whose operator still has a token."""
    operator, _, rest = cookie.partition("|")
    expires, _, mac = rest.partition("|")
    if not (operator and expires.isdigit() and mac):
        return None
    if not hmac.compare_digest(mac, _mac(settings, "session", operator, expires)):
        return None
    if int(expires) < now or operator not in settings.tokens.values():
        return None  # a removed token ends its sessions
    return operator


def csrf_token(settings: AuthSettings, credential: str) -> str:
    """The CSRF token bound to one credential (a session cookie or a proxy-asserted user)."""
    return _mac(settings, "csrf", credential)


def csrf_ok(settings: AuthSettings, credential: str, presented: str) -> bool:
    return bool(presented) and hmac.compare_digest(presented, csrf_token(settings, credential))
