"""The link's warnings: every timeout, resends at most once a minute with a count."""

from __future__ import annotations

import logging

import pytest

from hostd.link.actions import Notice
from hostd.link.notices import RESEND_INTERVAL, NoticeLog


def warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_resends_are_logged_once_an_interval_with_the_count_held_back(
        caplog: pytest.LogCaptureFixture) -> None:
    log = NoticeLog("/dev/ttyACM0")
    times = [0.0, 1.0, 2.0, 30.0, RESEND_INTERVAL + 0.5, RESEND_INTERVAL + 1.0,
             2 * RESEND_INTERVAL + 1.0]
    for i, t in enumerate(times):
        log.notice(Notice("resend", f"firmware asked for line {i} again"), t)
    assert warnings(caplog) == [
        "/dev/ttyACM0: firmware asked for line 0 again",
        "/dev/ttyACM0: firmware asked for line 4 again (3 more since the last one logged)",
        "/dev/ttyACM0: firmware asked for line 6 again (1 more since the last one logged)"]


def test_every_timeout_is_logged_whatever_the_resends(caplog: pytest.LogCaptureFixture) -> None:
    log = NoticeLog("sim://")
    log.notice(Notice("resend", "r1"), 0.0)
    for t in (0.1, 0.2, 0.3):
        log.notice(Notice("timeout", f"t{t}"), t)
    log.notice(Notice("resend", "r2"), 0.4)
    assert warnings(caplog) == ["sim://: r1", "sim://: t0.1", "sim://: t0.2", "sim://: t0.3"]
