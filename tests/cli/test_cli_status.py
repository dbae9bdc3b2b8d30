"""hostctl status: what it prints of the link."""

from __future__ import annotations

from hostd.cli.cmd_control import link_trouble


def test_link_trouble_names_the_counters_that_are_not_zero() -> None:
    assert link_trouble({"timeouts": 0, "resend_requests": 0, "reconnects": 0}) == ""
    assert link_trouble({"timeouts": 2, "resend_requests": 1, "checksum_errors": 0,
                         "resets": None}) == "2 ok timeouts, 1 resend request"
