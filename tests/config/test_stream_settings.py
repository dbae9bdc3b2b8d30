"""The streamer's own moves take their lift and speed from the configuration (``pause.*``),
and the defaults are what hostd always used: 10 mm up at 10 mm/s (F600)."""

from __future__ import annotations

from hostd.config import defaults, loads
from hostd.printer.settings import StreamSettings, stream_settings_from_config


def test_the_default_lift_is_the_one_hostd_always_used() -> None:
    settings = stream_settings_from_config(defaults())
    assert (settings.lift, settings.lift_f) == (10.0, 600.0)
    assert (settings.lift, settings.lift_f) == (StreamSettings().lift, StreamSettings().lift_f)


def test_the_lift_comes_from_the_pause_section() -> None:
    cfg = loads("pause:\n  lift: 25\n  lift_speed: 5\n", "x.yaml")
    settings = stream_settings_from_config(cfg)
    assert (settings.lift, settings.lift_f) == (25.0, 300.0)


def test_the_other_moves_use_the_slicers_values() -> None:
    """Retract, travel and the safe height are the process keys the slicer reads too."""
    cfg = loads("process:\n  retract_length: 2\n  retract_speed: 40\n  travel_speed: 100\n"
                "  safe_height: 30\n", "x.yaml")
    settings = stream_settings_from_config(cfg)
    assert (settings.retract, settings.retract_f) == (2.0, 2400.0)
    assert (settings.travel_f, settings.safe_height) == (6000.0, 30.0)
