"""Who is a cell operator: tokens, sessions, CSRF tokens."""

from __future__ import annotations

import pytest
from armnet_fms import auth

pytestmark = pytest.mark.unit

SETTINGS = auth.AuthSettings(secret_key=b"k" * 32, tokens={"t" * 20: "maria"}, session_ttl_s=100)


def test_an_operators_file_maps_tokens_to_names() -> None:
    assert auth.parse_tokens("# operators\nmaria:" + "t" * 20 + "\n\n") == {"t" * 20: "maria"}


@pytest.mark.parametrize("line", ["maria", "maria:short", "ma ria:" + "t" * 20, ":" + "t" * 20])
def test_a_bad_operators_line_says_what_is_expected(line: str) -> None:
    with pytest.raises(auth.AuthConfigError, match="line 1"):
        auth.parse_tokens(line)


def test_a_known_token_names_its_operator_and_others_none() -> None:
    assert auth.operator_for_token(SETTINGS, "t" * 20) == "maria"
    assert auth.operator_for_token(SETTINGS, "x" * 20) is None


def test_a_session_is_valid_until_it_expires() -> None:
    cookie = auth.make_session(SETTINGS, "maria", 1000)
    assert auth.session_operator(SETTINGS, cookie, 1099) == "maria"
    assert auth.session_operator(SETTINGS, cookie, 1101) is None


def test_a_session_with_a_changed_name_is_refused() -> None:
    cookie = auth.make_session(SETTINGS, "maria", 1000)
    assert auth.session_operator(SETTINGS, "admin" + cookie[len("maria"):], 1000) is None


def test_a_removed_token_ends_its_operators_sessions() -> None:
    cookie = auth.make_session(SETTINGS, "maria", 1000)
    without = auth.AuthSettings(secret_key=SETTINGS.secret_key, tokens={})
    assert auth.session_operator(without, cookie, 1000) is None


def test_a_csrf_token_is_bound_to_its_credential() -> None:
    token = auth.csrf_token(SETTINGS, "session-a")
    assert auth.csrf_ok(SETTINGS, "session-a", token)
    assert not auth.csrf_ok(SETTINGS, "session-b", token)
    assert not auth.csrf_ok(SETTINGS, "session-a", "")
