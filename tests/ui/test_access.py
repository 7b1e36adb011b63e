"""Who may use the page: loopback, the token, one controlling browser with a lease."""

from __future__ import annotations

import pytest

from microcal.ui.access import Control, is_loopback, new_token, token_matches


@pytest.mark.parametrize(("host", "loopback"), [
    ("127.0.0.1", True), ("127.3.2.1", True), ("::1", True), ("[::1]", True), ("localhost", True),
    ("0.0.0.0", False), ("192.0.2.7", False), ("lab-pc.example", False), ("::", False),
])  # fmt: skip
def test_only_loopback_goes_without_a_token(host: str, loopback: bool):
    assert is_loopback(host) is loopback


def test_tokens_are_fresh_and_compared_whole():
    a, b = new_token(), new_token()
    assert a != b
    assert len(a) >= 40
    assert token_matches(a, a)
    assert not token_matches(None, a)
    assert not token_matches(a[:-1], a)
    assert not token_matches(b, a)


def test_one_browser_controls_until_its_lease_runs_out():
    now = [0.0]
    control = Control(lease_s=5.0, clock=lambda: now[0])
    assert not control.held()
    assert control.claim("first")
    assert not control.claim("second")  # watches
    assert control.controls("first")
    assert not control.controls("second")
    now[0] = 4.0
    assert control.renew("first")
    assert not control.renew("second")
    now[0] = 8.0  # renewed at 4: still held
    assert not control.claim("second")
    now[0] = 9.5  # no poll for 5.5 s: the lease ran out
    assert not control.controls("first")
    assert not control.held()
    assert control.claim("second")
    assert not control.renew("first")
    control.release("first")  # not the holder: nothing changes
    assert control.controls("second")
    control.release("second")
    assert not control.held()
