"""hostctl decompose: its options keep the bounds of the config keys they override."""

from __future__ import annotations

import pytest

from hostd.cli.main import main


@pytest.mark.parametrize(("option", "value", "bounds"), [
    ("--parts", "65", "[0, 64] (as decompose.parts)"),
    ("--parts", "-1", "[0, 64] (as decompose.parts)"),
    ("--seed", "2147483648", "[0, 2147483647] (as decompose.seed)"),
    ("--seed", "-3", "[0, 2147483647] (as decompose.seed)"),
])
def test_an_option_past_its_keys_bounds_is_one_line_exit_2(tmp_path, capsys, option, value,
                                                          bounds):
    rc = main(["decompose", "/work/never-read.stl", "-o", str(tmp_path / "o"), option, value])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == f"hostctl: {option} {value}: must lie in {bounds}"
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("verb", ["slice", "decompose"])
def test_without_config_the_printers_installed_config_is_used(tmp_path, capsys, monkeypatch,
                                                             verb):
    """On the printer's computer an offline slice is for that printer: without ``--config``
    the installed file is read (here one with a wrong key, which names it), and where there
    is none, the shipped defaults."""
    import hostd.config.paths as paths

    installed = tmp_path / "hostd.yaml"
    installed.write_text("machine:\n  name: mine\n  bogus: 1\n")
    monkeypatch.setattr(paths, "INSTALLED_CONFIG", installed)
    rc = main([verb, "/work/never-read.stl", "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and str(installed) in err and "machine.bogus" in err
    assert paths.offline_config() == installed
    installed.unlink()
    assert paths.offline_config() == paths.DEFAULT_CONFIG
